"""The accelerometer's calibrate step: its design, estimators and section."""
