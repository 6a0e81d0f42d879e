"""Geometry: oriented boxes and polylines, coordinate frames (ours and SUMO's), the drivable area."""
