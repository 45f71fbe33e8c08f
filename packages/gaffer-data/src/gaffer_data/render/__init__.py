"""Blender rendering of relighting datasets.

Only modules under this package import `bpy`, and only inside worker subprocesses (`worker.py`,
`procedural.py`); importing `gaffer_data.render` itself does not import bpy.
"""
