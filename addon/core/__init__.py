"""Pure core of Silhouette Cloth Fit: never imports ``bpy``.

Path of the data, one module each:
capture (I/O) -> model/simulate -> camera -> raster -> metrics -> objective -> optimise,
with ``experiment`` running the paper's protocol on top.
"""
