"""The gyroscope's estimators: the full model from integrated rotations (its model,
integration, start and sigma points), the per-axis approaches and the known-angle turns."""
