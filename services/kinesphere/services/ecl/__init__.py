"""The Embodied Configuration Library: the VSAM, the SQLite databank and f_SB lookups.

Submodules are imported on demand (``vsam``, ``store``, ``ecl``, ``cli``), so importing the
package stays cheap for processes that only need one of them.
"""
