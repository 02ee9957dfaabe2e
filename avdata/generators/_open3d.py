"""The one place where avdata loads Open3D.

Open3D's wheel links against libusb, libGL/libEGL, libX11 and libudev. libusb is shipped by the
``libusb-package`` wheel but not on the loader's path, so it is loaded first with ``RTLD_GLOBAL``;
a missing system library becomes an :class:`~avdata.errors.AvdataError` that names it instead of a
bare ``ImportError`` from deep inside Open3D.
"""

from __future__ import annotations

import ctypes
import re
from types import ModuleType

from avdata.errors import AvdataError

_SYSTEM_LIBRARIES = ("libGL", "libEGL", "libX11", "libudev", "libusb", "libgomp")


def load_open3d() -> ModuleType:
    """Imports Open3D after preloading libusb.

    Returns:
        The ``open3d`` module.

    Raises:
        AvdataError: a shared library Open3D needs is missing, naming it.
    """
    try:
        import libusb_package

        libusb = libusb_package.get_library_path()
        if libusb is None:
            raise OSError("libusb-1.0.so: not found by libusb_package")
        ctypes.CDLL(str(libusb), mode=ctypes.RTLD_GLOBAL)
        import open3d
    except (ImportError, OSError) as error:
        text = str(error)
        match = re.search(r"(lib[\w.+-]+\.so[\w.]*)", text)
        library = match.group(1) if match else next((n for n in _SYSTEM_LIBRARIES if n in text), None)
        if library is None:
            raise AvdataError(
                f"expected Open3D to import (pip install 'avdata[sim]'), got ImportError: {text}"
            ) from error
        raise AvdataError(
            f"expected system library {library} for Open3D's ray casting, got it missing "
            f"(install libGL/libEGL/libX11/libudev, e.g. apt-get install libgl1 libegl1 libx11-6 libudev1): "
            f"{text}"
        ) from error
    return open3d


o3d = load_open3d()
