"""Shared fixtures. BLAS threads are pinned to 1: see shared/reference/measured-pitfalls.md."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
