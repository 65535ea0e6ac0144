"""Root test configuration.

OMP_WAIT_POLICY=PASSIVE must be set before torch is imported: torch's OpenMP threads
otherwise spin between parallel regions and slow the numba kernels several-fold on a
2-core machine (see ebad/cli/__init__.py).
"""
import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
