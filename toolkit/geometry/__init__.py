"""Geometry every stage shares: rotations, frames, sensor mounts, WGS-84."""
