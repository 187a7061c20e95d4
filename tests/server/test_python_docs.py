"""docs/python.md runs as written: its Python blocks, in order, in one namespace, from the project's folder, with
``SERVICE`` the address of a real service (its store holding an accepted calibration of wearable-7)."""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

from server_fixtures import ROOT, RunningService

from calib.io.readers import write_native_csv
from calib.simulator import simulate

DOC = ROOT / "docs" / "python.md"


def blocks(text: str) -> list[str]:
    """The doc's ```python blocks, in order."""
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_python_docs_run_as_written(tmp_path: Path, real_data: Path) -> None:
    svc = RunningService([], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        with svc.client() as c:
            rec, _ = simulate(2, noise=0.03)
            buf = io.StringIO()
            write_native_csv(rec, buf)
            r = c.post("/devices/wearable-7/calibrate", content=buf.getvalue(), headers={"Content-Type": "text/csv"},
                       params={"sensor_model": "ICM-20948", "firmware": "1.2.0"})
            assert r.status_code == 200 and r.json()["passed"], r.text
            accepted = c.post(f"/sessions/{r.json()['session_id']}/accept")
            assert accepted.status_code == 200, accepted.text
        code = blocks(DOC.read_text(encoding="utf-8"))
        assert len(code) >= 10
        script = tmp_path / "python_docs.py"
        body = "\n".join(f"# --- block {i + 1}\n{b}" for i, b in enumerate(code)).replace("../shared/data/real", str(real_data))
        script.write_text(f"SERVICE = {svc.base!r}\n{body}", encoding="utf-8")
        run = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=240)
        assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
        out = run.stdout
        assert "protocol: ferraris" in out and "k in force:" in out and "no-such-wearable" in out
        assert "gyroscope_noise_density:" in out and "Tw:" in out
        assert (ROOT / "artifacts" / "python-docs" / "allan.png").read_bytes()[:4] == b"\x89PNG"
    finally:
        svc.stop()


def test_importing_calib_loads_none_of_the_services_dependencies() -> None:
    probe = ("import sys, calib; calib.read; "
             "bad = [m for m in ('fastapi', 'sqlalchemy', 'uvicorn', 'bleak', 'scipy', 'matplotlib', 'server') if m in sys.modules]; "
             "print(bad)")
    run = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == "[]", run.stdout + run.stderr
