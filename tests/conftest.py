"""Test configuration shared by the whole suite.

Under CI (``CI`` set in the environment) hypothesis runs derandomized: the same examples
every run, so a landing is never decided by a new random draw. Locally it explores new
examples each run (and keeps failures in .hypothesis/).
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
