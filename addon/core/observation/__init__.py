"""What cameras see: cameras and rigs, the rasteriser and its kernels, the silhouette error,
the capture format, synthetic captures and overlays.
"""
