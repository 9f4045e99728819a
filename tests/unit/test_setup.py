"""setup.py's build hook, piece by piece: which commands run mypyc, the compiler probe, and
the build that compiles every module or none.  ``tests/integration/
test_build_without_compiler.py`` builds a whole wheel without a compiler."""

from __future__ import annotations

import runpy
import sys
import sysconfig
from pathlib import Path
from typing import Any

import pytest
from setuptools import Distribution, Extension

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def hook(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """setup.py's names, without its ``setup()`` call (it runs only as ``__main__``)."""
    monkeypatch.chdir(ROOT)  # it reads dbc/runtime/compiled.py relative to its directory
    monkeypatch.delenv("WHEELCHAIR_HIL_PURE_PYTHON", raising=False)
    return runpy.run_path(str(ROOT / "setup.py"), run_name="wheelchair_hil_setup")


@pytest.mark.parametrize("argv", [["egg_info"], ["dist_info", "--output-dir", "x"], ["--name"]])
def test_the_metadata_hooks_run_no_mypyc(
    hook: dict[str, Any], monkeypatch: pytest.MonkeyPatch, argv: list[str]
) -> None:
    monkeypatch.setattr(sys, "argv", ["setup.py", *argv])
    assert hook["ext_modules"]() == []


def test_no_compiler_is_found_before_mypyc_runs(
    hook: dict[str, Any], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # this machine compiles: make install built the compiled modules with it
    err = hook["c_compiler_error"]()
    assert err is None, f"no C compiler or Python headers here ({err}): make install said so"
    monkeypatch.setenv("CC", "/bin/false")
    assert hook["c_compiler_error"]() is not None
    monkeypatch.setattr(sys, "argv", ["setup.py", "bdist_wheel"])
    assert hook["ext_modules"]() == []
    assert "WARNING: compiling failed" in capsys.readouterr().err


def test_a_module_that_fails_to_compile_leaves_none_built(
    hook: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The first module compiles and links; the second does not: neither is left, and the
    build says the package is pure Python (a compiled module whose group library is missing
    would not import)."""
    (tmp_path / "good.c").write_text(
        "#include <Python.h>\n"
        'static struct PyModuleDef m = {PyModuleDef_HEAD_INIT, "good", NULL, -1, NULL};\n'
        "PyMODINIT_FUNC PyInit_good(void) { return PyModule_Create(&m); }\n"
    )
    (tmp_path / "bad.c").write_text("#include <Python.h>\nthis is not C;\n")
    dist = Distribution(
        {
            "name": "probe",
            "ext_modules": [
                Extension("good", [str(tmp_path / "good.c")]),
                Extension("bad", [str(tmp_path / "bad.c")]),
            ],
        }
    )
    cmd = hook["AllOrNothingBuildExt"](dist)
    cmd.build_lib = str(tmp_path / "lib")
    cmd.build_temp = str(tmp_path / "tmp")
    cmd.parallel = 1  # in order: good is built before bad fails
    cmd.include_dirs = [sysconfig.get_paths()["include"]]
    cmd.ensure_finalized()
    cmd.run()
    assert cmd.extensions == []
    assert not list((tmp_path / "lib").rglob("*.so")), "a built module was left"
    assert list((tmp_path / "tmp").rglob("good*.o")), "good.c was never compiled"
    assert "WARNING: compiling failed" in capsys.readouterr().err
