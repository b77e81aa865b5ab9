"""Lens file input/output: the deeplens JSON format and the paper authors' table format."""

from ..errors import LensFileError
from .lensfile import lens_from_dict, lens_to_dict, read_json, save_lens
from .load import load_lens
from .table import read_table, table_to_dict

__all__ = ["LensFileError", "lens_from_dict", "lens_to_dict", "load_lens", "save_lens",
           "read_json", "read_table", "table_to_dict"]
