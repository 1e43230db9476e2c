"""Test-session settings shared by every test module.

BLAS threads: the suite solves many small problems (QR of a few thousand rows, 2×2 to 20×20
LMIs). Multi-threaded OpenBLAS gains nothing there and, on a loaded 2-core machine, its spinning
threads make a 2000×9 QR ~500× slower (measured: 0.1 s vs 0.2 ms). This must be set before numpy
is imported, which is why it lives here and not in a fixture.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
