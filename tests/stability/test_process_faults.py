"""Process faults: a writer killed mid-write and a full disk never leave a corrupt file."""

import hashlib
import os
import resource
import signal
import subprocess
import sys
import time

from tests.helpers import REPO, run_cli

WRITER = """
import hashlib, sys
from backend import fsio
path, n = sys.argv[1], int(sys.argv[2])
for i in range(10**6):
    body = bytes([i % 251]) * n
    fsio.write_bytes(path, hashlib.sha256(body).hexdigest().encode() + b"\\n" + body)
    print(i, flush=True)
"""


def _intact(path):
    digest, body = path.read_bytes().split(b"\n", 1)
    return hashlib.sha256(body).hexdigest().encode() == digest


def test_writer_killed_mid_write_leaves_last_complete_file(tmp_path):
    target = tmp_path / "snapshot.bin"
    for delay in (0.3, 0.55, 0.8):
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(target), str(8 << 20)], cwd=REPO,
                                stdout=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(REPO)))
        proc.stdout.readline()  # at least one complete write
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert _intact(target), f"torn file after SIGKILL at {delay}s"


def _limit_file_size():
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG instead
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 << 10, 64 << 10))


def test_full_disk_gives_one_line_error_and_no_output(tmp_path):
    out = tmp_path / "capture"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run([sys.executable, "-m", "backend", "synth", "--out", str(out), "--views", "2",
                           "--resolution", "48", "--spp", "4", "--held-out", "0"], cwd=REPO, env=env,
                          capture_output=True, text=True, preexec_fn=_limit_file_size, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in proc.stderr
    assert "too large" in lines[0] or "no space" in lines[0]
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir()], "temporary output left behind"


def test_cli_rejects_existing_output_folder(tmp_path):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("user data")
    proc = run_cli("synth", "--out", tmp_path / "taken", "--views", 2, "--resolution", 32)
    assert proc.returncode == 2 and "exists and is not empty" in proc.stderr
    assert (tmp_path / "taken" / "keep.txt").read_text() == "user data"
