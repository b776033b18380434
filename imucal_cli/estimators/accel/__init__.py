"""The accelerometer's estimators: Qureshi & Golnaraghi's gravity-magnitude fit, the
labelled-pose fit, their Cramer-Rao bounds."""
