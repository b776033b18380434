"""imucal: calibrate MEMS accelerometers and gyroscopes from a session file."""

import os

# The solvers factor matrices of a few thousand rows by tens of columns: BLAS threads only add
# overhead there (up to 50x the CPU time of one thread on a busy 2-core machine). Set before
# numpy is first imported; a value the user set wins.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
