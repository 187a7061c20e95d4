"""What `make run` installs carries everything the run path imports, and a part that cannot be imported says which
module failed and what installs it (never 'not installed' when an import failed)."""

from __future__ import annotations

import ast
import sys
from importlib.metadata import requires
from pathlib import Path

import pytest

from calib.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
RUN_PACKAGES = ("calib", "server", "mock_device", "wearable_protocol", "webui")
RUN_EXTRAS = ("server", "ble")  # what the Makefile's run target installs: pip install -e '.[server,ble]'
# import names that differ from their distribution's name
DISTRIBUTION_OF = {"multipart": "python-multipart", "python_multipart": "python-multipart", "yaml": "pyyaml",
                   "starlette": "fastapi"}  # FastAPI's own foundation, installed and pinned by it


def _third_party_imports() -> dict[str, set[str]]:
    """Top-level modules imported anywhere in the run path's packages, with the files that import them."""
    ours = set(RUN_PACKAGES)
    stdlib = set(sys.stdlib_module_names)
    found: dict[str, set[str]] = {}
    for package in RUN_PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                names: list[str] = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                for name in names:
                    top = name.split(".")[0]
                    if top not in ours and top not in stdlib and top != "__future__":
                        found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


def _installed_by_run() -> set[str]:
    """Distribution names (normalised) that the base install and the run extras require."""
    names = set()
    for requirement in requires("gyrocal") or []:
        name, _, marker = requirement.partition(";")
        dist = name.strip().split("[")[0]
        for sep in "<>=!~ ":
            dist = dist.split(sep)[0]
        extra = marker.split("extra ==")[-1].strip().strip("'\"") if "extra ==" in marker else None
        if extra is None or extra in RUN_EXTRAS:
            names.add(dist.replace("_", "-").lower())
    return names


def test_the_run_extras_carry_every_module_the_run_path_imports() -> None:
    installed = _installed_by_run()
    missing = {}
    for module, files in _third_party_imports().items():
        dist = DISTRIBUTION_OF.get(module, module).replace("_", "-").lower()
        if dist not in installed:
            missing[module] = sorted(files)
    assert not missing, f"imported by the run path but not in the base dependencies or the {RUN_EXTRAS} extras: {missing}"


def _hide_module(monkeypatch: pytest.MonkeyPatch, hidden: str, reloaded: tuple[str, ...]) -> None:
    """Make ``import hidden`` fail as a missing package would, and forget ``reloaded`` so they import it again."""
    for name in list(sys.modules):
        if name.split(".")[0] in (*reloaded, hidden):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, hidden, None)  # type: ignore[arg-type]


def test_serve_mock_names_the_module_that_failed_and_the_install_command(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _hide_module(monkeypatch, "httpx", ("mock_device",))
    assert main(["serve", "--mock", "1", "--db", "sqlite://"]) == 2
    err = capsys.readouterr().err
    assert "--mock needs the simulated wearables" in err
    assert "the module 'httpx' could not be imported" in err
    assert "pip install 'gyrocal[server]'" in err
    assert "not installed" not in err


@pytest.mark.timeout(60)
def test_a_command_whose_part_cannot_be_imported_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _hide_module(monkeypatch, "fastapi", ("server", "mock_device"))
    assert main(["serve", "--mock", "1", "--db", "sqlite://"]) == 2
    err = capsys.readouterr().err
    assert "'gyrocal serve' needs the module 'fastapi', which could not be imported" in err
    assert "pip install 'gyrocal[server]'" in err
    assert "Traceback" not in err


def test_an_unknown_bench_method_and_one_whose_dependency_is_missing_are_told_apart(monkeypatch: pytest.MonkeyPatch) -> None:
    from calib.errors import GyrocalError
    from calib.estimators import registry

    with pytest.raises(GyrocalError, match="unknown bench method 'no_such_method'"):
        registry.batch_estimator("no_such_method")

    def import_needing_httpx(name: str) -> None:
        raise ModuleNotFoundError("No module named 'httpx'", name="httpx")

    watched = registry.Estimator("calib.estimators.watched:calibrate_watched", "calib.estimators.watched:watched_batch")
    monkeypatch.setitem(registry.ESTIMATORS, "watched", watched)
    monkeypatch.setattr(registry, "import_module", import_needing_httpx)
    for load in (registry.batch_estimator, registry.estimator):
        with pytest.raises(GyrocalError, match="the estimator calib.estimators.watched:.* cannot be loaded: the module 'httpx' "
                                               "could not be imported"):
            load("watched")


def test_a_command_whose_entry_point_cannot_be_loaded_is_listed_and_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from importlib.metadata import EntryPoint

    broken = EntryPoint(name="serve", value="fastapi_missing_here.cli:register", group="gyrocal.commands")
    monkeypatch.setattr("calib.cli.main.entry_points", lambda group: [broken])
    assert main(["serve", "--mock", "2"]) == 2
    err = capsys.readouterr().err
    assert "'gyrocal serve' cannot be loaded: the module 'fastapi_missing_here' could not be imported" in err
    assert "install it with: pip install" in err


def test_a_database_driver_that_is_not_installed_is_named_with_its_install_command() -> None:
    from server.store.engine import engine_for
    from server.store.errors import StoreError

    with pytest.raises(StoreError, match=r"the module 'psycopg2' could not be imported .*install it with: pip install psycopg2"):
        engine_for("postgresql+psycopg2://gyrocal@127.0.0.1/gyrocal")
