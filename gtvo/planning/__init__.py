"""Path planning on occupancy grids built from the VO map: A* and the grid builder."""
