"""smorphi-rl: find the best shape for the Smorphi reconfigurable floor-cleaning robot on a map.

The core (geometry -> maps -> coverage) imports numpy, and for map files Pillow, PyYAML and SciPy; the
compiled fast path loads numba lazily, on the first evaluation.
"""

__version__ = "0.1.0"
