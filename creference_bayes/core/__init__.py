"""The pure numerical core: units, geometry (camera, box, projection), ground-plane metrology,
the paper's costs and the error measures. NumPy and SciPy only.
"""
