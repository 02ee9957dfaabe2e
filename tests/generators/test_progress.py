"""Generation reports progress per frame on a terminal, and nothing at all with --quiet (no pybullet banner)."""

from __future__ import annotations

import fcntl
import os
import pty
import struct
import subprocess
import sys
import termios
from pathlib import Path


def test_quiet_prints_nothing(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "generate", "--preset", "v2i-intersection", "--frames", "1",
                           "--seed", "2", "--quiet", str(tmp_path / "out")], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == "" and proc.stderr == ""


def test_frame_bar_on_a_terminal(tmp_path: Path) -> None:
    main_fd, terminal_fd = pty.openpty()
    # A terminal of 24 x 100 characters (a fresh pty has size 0 x 0, where tqdm draws an empty bar).
    fcntl.ioctl(terminal_fd, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "avdata.cli", "generate", "--preset", "v2i-intersection", "--frames", "2",
                             "--seed", "2", str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=terminal_fd)
    os.close(terminal_fd)
    seen = b""
    while True:
        try:
            chunk = os.read(main_fd, 4096)
        except OSError:  # the terminal closed: the child exited
            break
        if not chunk:
            break
        seen += chunk
    out, _ = proc.communicate(timeout=600)
    os.close(main_fd)
    assert proc.returncode == 0
    assert b"scene_000002_0000" in seen and b"2/2" in seen and b"frame" in seen
    assert b"pybullet build time" not in seen
    assert out.decode().startswith("generate: 1 scenes written, 0 already complete, 0 failed")
