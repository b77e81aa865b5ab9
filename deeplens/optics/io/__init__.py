"""Lens file input/output: the deeplens JSON format, the paper authors' table format, and Zemax
``.zmx`` lens files with ``.agf`` glass catalogues, and CODE V ``.seq`` files."""

from ..errors import LensFileError
from .lensfile import lens_from_dict, lens_to_dict, read_json, save_lens
from .agf import GlassCatalogue, read_agf
from .codev import CodeVWarning, read_seq, write_seq
from .load import load_lens
from .table import read_table, table_to_dict
from .zmx import ZemaxFileError, ZemaxWarning, read_zmx, write_zmx

__all__ = ["LensFileError", "lens_from_dict", "lens_to_dict", "load_lens", "save_lens",
           "read_json", "read_table", "table_to_dict", "read_zmx", "write_zmx", "ZemaxFileError",
           "ZemaxWarning", "read_agf", "GlassCatalogue", "read_seq", "write_seq",
           "CodeVWarning"]
