"""Test configuration shared by the whole suite.

Under CI (``CI`` set in the environment) hypothesis runs derandomized: the same examples
every run, so a landing is never decided by a new random draw. Locally it explores new
examples each run (and keeps failures in .hypothesis/).
"""

import os

import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")



@pytest.fixture
def gmsh_unwatched(monkeypatch):
    """`mesh_cad`'s gmsh attempts run in this process, not in a watched child
    (`cadbridge.mesh.gmsh.isolated.WATCH`): for tests that record what happens inside them."""
    monkeypatch.setattr("cadbridge.mesh.gmsh.isolated.WATCH", False)
