"""Image pipeline: frame pairs to ranges (thesis ch. 6.1, 6.3, Algorithm 2)."""
