"""Judging 3D labels the way the field judges 3D boxes: 3D and bird's-eye IoU, KITTI's average
precision with the official devkit's rules, and the reliability of the labels' quality scores
(docs/evaluation.md).
"""
