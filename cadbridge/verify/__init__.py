"""Cross-checks against OpenCASCADE (OCP): a reference IGES reader and the `verify` engine.

Outside the core: nothing in iges/nurbs/mesh/normals/nagata imports this package.
Import the submodules directly (``cadbridge.verify.reference``, ``cadbridge.verify.faces``).
"""
