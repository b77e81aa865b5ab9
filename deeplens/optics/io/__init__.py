"""Lens file input/output: the deeplens JSON format and the paper authors' table format."""

from .lensfile import LensFileError, lens_from_dict, lens_to_dict, load_lens, save_lens
from .table import read_table, table_to_dict

__all__ = ["LensFileError", "lens_from_dict", "lens_to_dict", "load_lens", "save_lens",
           "read_table", "table_to_dict"]
