"""Adapters to image libraries: the horizon from an image (OpenCV) and the figures (matplotlib).
"""
