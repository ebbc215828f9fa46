"""Warp kernels with thin numpy-in/numpy-out wrappers; each takes a `device` argument."""
import warp as _wp

import logging as _logging

_wp.config.log_level = _logging.WARNING  # no banner or per-module load lines
_wp.config.enable_backward = False  # forward-only kernels compile faster
