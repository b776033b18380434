"""The gyroscope's calibrate step: turns and still periods, its design, estimators and section."""
