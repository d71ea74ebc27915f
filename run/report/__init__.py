"""docs/report.md and the studies behind it (the voxel ladders, the model cards)."""
