"""Raycasting simulator: scenes, drives, scenarios and the simulator itself."""
