"""The Open3D loader turns a missing shared library into an AvdataError that names it."""

from __future__ import annotations

import ctypes
import sys

import pytest

from avdata.errors import AvdataError
from avdata.generators import _open3d


def test_missing_system_library_is_named(monkeypatch):
    def missing(path, mode=0):
        raise OSError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")

    monkeypatch.setattr(ctypes, "CDLL", missing)
    with pytest.raises(AvdataError, match=r"expected system library libusb-1.0.so.0 for Open3D"):
        _open3d.load_open3d()


def test_missing_open3d_package_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "open3d", None)
    with pytest.raises(AvdataError, match=r"pip install 'avdata\[sim\]'"):
        _open3d.load_open3d()
