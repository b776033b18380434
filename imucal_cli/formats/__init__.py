"""File formats, one module each: the session (HDF5), the calibration (JSON), the calibrate
config (TOML), the column spec of text streams, and the importers and exporters of other
tools' files. Everything that reads or writes bytes lives here; nothing here solves."""
