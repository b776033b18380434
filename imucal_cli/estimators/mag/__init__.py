"""The magnetometer's estimator: the magnitude fit with the rotation onto the accelerometer,
its start and its Cramer-Rao bound."""
