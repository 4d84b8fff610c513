"""Suite-wide settings.

Hypothesis deadlines are off: the first call of a numba-compiled function includes its
compilation (or cache load), and speed goals live in ``frhc bench``, not in timed tests.
"""

from hypothesis import settings

settings.register_profile("frhc", deadline=None)
settings.load_profile("frhc")
