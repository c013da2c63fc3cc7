"""Suite-wide settings. Under CI (``CI=1``, set by ``.ci/run``) hypothesis draws the same
examples on every run, so a landing is judged on a fixed set; elsewhere each run explores new
ones (that is how the lying-header case of ``test_fuzz_hostile.py`` was found)."""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
