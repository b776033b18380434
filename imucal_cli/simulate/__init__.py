"""The virtual IMU: sessions with known truth for tests, benchmarks and demos.

``triad`` (the accelerometer/gyro triad and the pose plans), ``redundant`` (Hwangbo & Kanade's
redundant unit and right-angle iron), ``rotations`` (Qureshi's hand rotations, free
rotations), ``device`` (a live virtual serial port, ``imucal simulate --serve``)."""
