"""The estimators, grouped by sensor (accel, gyro, mag, thermal, clock) beside the ones two
sensors share (the factorization of a unit, the algebraic ellipsoid). Pure: arrays in, typed
results out; named as the papers name them, equations cited."""
