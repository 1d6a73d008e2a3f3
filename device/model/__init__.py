"""Pure sensor math without I/O: camera projection, triangulation, scan frame, eye safety,
background light. Small stateless functions on numpy arrays (thesis ch. 3, app. D)."""
