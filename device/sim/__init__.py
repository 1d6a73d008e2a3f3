"""Scene simulator with ground truth: renderer, scenes, sensor noise and timing (thesis ch. 6, app. A)."""
