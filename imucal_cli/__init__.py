"""imucal: calibrate MEMS accelerometers and gyroscopes from a session file."""

__version__ = "0.1.0"
