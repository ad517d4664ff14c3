"""CAD files in: the format by content, one `Model` for IGES and STEP (`read_cad`)."""

from cadbridge.formats.read import cad_format, read_cad

__all__ = ["cad_format", "read_cad"]
