"""The typed calibration model: a :class:`~.calibration.Calibration` of typed sections (one
class per sensor, :mod:`.accel`, :mod:`.gyro`, :mod:`.mag`, and the simulator's
:mod:`.truth`), the records they share (:mod:`.parts`), the session model (:mod:`.session`),
and the codec between records and the JSON's objects (:mod:`.codec`)."""
