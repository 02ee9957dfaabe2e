"""Unified datasets written in other datasets' layouts: ``kitti`` (KITTI object) and ``nuscenes`` (13 tables)."""
