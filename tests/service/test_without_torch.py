"""The service runs where torch (and onnx) are not installed: ``python -m tactilesnn.service``
in a deployment of numpy, onnxruntime, starlette and uvicorn (measured in a fresh venv of 188 MB;
here torch and onnx are blocked from importing in a subprocess)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.helpers import exported_model

SMALL = {"seed": 0, "n_planar": 6, "n_concave": 3, "n_convex": 3, "n_test": 2}

CODE = """
import io, sys
for name in ("torch", "onnx"):
    sys.modules[name] = None  # as if not installed: importing them raises ImportError
import numpy as np
from starlette.testclient import TestClient
from tactilesnn.service.app import create_app
from tactilesnn.service.command import main
x = np.load(sys.argv[2])
with TestClient(create_app(sys.argv[1]), base_url="http://127.0.0.1") as c:
    buf = io.BytesIO(); np.save(buf, x)
    r = c.post("/v1/classify", content=buf.getvalue(), headers={"content-type": "application/x-npy"})
    assert r.status_code == 200, r.text
    print(",".join(r.json()["classes"]))
assert "torch" not in {m.split(".")[0] for m in sys.modules if sys.modules[m] is not None}
print(main(["/no/such/model.onnx"]))
"""


@pytest.mark.slow
def test_the_service_classifies_without_torch_or_onnx(tmp_path):
    import numpy as np

    path, pipe, test = exported_model(tmp_path, SMALL)
    np.save(tmp_path / "x.npy", test.X[:4])
    out = subprocess.run([sys.executable, "-c", CODE, str(path), str(tmp_path / "x.npy")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.strip().splitlines()
    assert lines[0].split(",") == [pipe.class_names[i] for i in pipe.predict(test.X[:4])]
    assert lines[-1] == "2" and "does not exist" in out.stderr
