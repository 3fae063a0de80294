"""Former home of the instance reader and writer, kept so existing imports work.

The parser is :mod:`camplace.instance.parse`, mesh files :mod:`camplace.instance.meshio`, the
writer :mod:`camplace.instance.write`.
"""

from camplace.instance.meshio import make_winding_consistent, read_mesh_file
from camplace.instance.parse import load_instance, parse_instance
from camplace.instance.write import save_instance

__all__ = ["load_instance", "parse_instance", "save_instance", "read_mesh_file", "make_winding_consistent"]
