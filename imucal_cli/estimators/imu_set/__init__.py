"""The estimators of a set of several IMUs on one body (the spec's "Several IMUs"): the set's
accelerometers fitted jointly (``accel``), the rotation of each IMU onto the reference from
vector pairs (``rotation``), and the time offsets from the gyro signals (``time_offset``)."""
