"""rtcal's public face (issue 41, items 1 and 4): ``rtcal.api`` names everything a method or an instrument kind may
use and loads nothing until a name is used; rtcal ships ``py.typed``, so ``mypy --strict`` checks the sample
plugins against an installed rtcal; every name that moved still works for one release, with a
DeprecationWarning; and the registries are lazy and equal — a built-in registered as a plugin is, loaded on
first use, so that a module of one method's folder loads no other method."""

from __future__ import annotations

import ast
import importlib
import json
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

import rtcal.api as api

REPO = Path(__file__).resolve().parents[1]
PROJECT = ("rtcal", "drivers", "simulators")
LOADED = f"import json, sys; print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in {PROJECT!r})))"


def _loaded_by(statement: str) -> set[str]:
    """The project's modules a fresh interpreter holds after ``statement``."""
    done = subprocess.run([sys.executable, "-c", f"{statement}\n{LOADED}"], capture_output=True, text=True, timeout=120,
                          cwd=REPO)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


def test_every_name_of_the_face_is_what_the_type_checker_sees():
    """The names the face serves at run time (its table) are those its TYPE_CHECKING imports give the type checker,
    each the object of the module named."""
    tree = ast.parse((REPO / "rtcal" / "api.py").read_text(encoding="utf-8"))
    guarded = next(n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING")
    seen = {(i.module, a.asname or a.name) for i in guarded.body if isinstance(i, ast.ImportFrom) for a in i.names}
    served = {(module, name) for module, names in api._WHERE.items() for name in names}
    assert seen == served
    for module, name in sorted(served):
        assert getattr(api, name) is getattr(importlib.import_module(module), name), name
    with pytest.raises(AttributeError, match="rtcal.api's names"):
        api.NoSuchName  # noqa: B018


def test_the_face_loads_nothing_until_a_name_is_used():
    assert _loaded_by("import rtcal.api") == {"rtcal", "rtcal.api"}
    used = _loaded_by("from rtcal.api import Move")
    assert "rtcal.engine.steps" in used and not any(m.startswith(("rtcal.methods", "simulators", "rtcal.store")) for m in used)


def test_a_method_folders_module_loads_only_its_own_folder():
    """`import rtcal.methods.abbe.results` loads that folder and the results model, not the other method (nor the
    engine, the store, the simulators or any method's code)."""
    loaded = _loaded_by("import rtcal.methods.abbe.results")
    assert {"rtcal.methods.abbe", "rtcal.methods.abbe.results", "rtcal.results.model"} <= loaded
    assert not [m for m in loaded if m.startswith(("rtcal.methods.multistation", "rtcal.engine", "rtcal.store", "simulators",
                                                   "rtcal.methods.abbe.method"))], loaded


def test_the_registries_are_lazy_and_equal():
    """Methods, kinds, driver models and compensation formats are one Registry each; their built-in ones are named
    as a plugin's are (``module:attribute``) and asking for one method loads no other."""
    from drivers.kinds import KINDS
    from drivers.models import MODELS
    from rtcal.compensation.registry import FORMATS
    from rtcal.methods import BUILTIN, METHODS
    from rtcal.registry import Registry

    assert all(isinstance(r, Registry) for r in (METHODS, KINDS, MODELS, FORMATS))
    assert all(":" in target for target in BUILTIN.values())
    loaded = _loaded_by("from rtcal.methods import METHODS\nMETHODS['encoder_abbe_error'].results_model")
    assert "rtcal.methods.abbe.method" in loaded and not any(m.startswith("rtcal.methods.multistation") for m in loaded)
    assert list(METHODS.builtin_names()) == list(BUILTIN) and METHODS.names()[:len(BUILTIN)] == tuple(BUILTIN)


MOVED = [  # (where a name was, the name, where it is now)
    ("rtcal.store.dataset", "multistation_data", "rtcal.methods.multistation.dataset"),
    ("rtcal.store.dataset", "abbe_visits", "rtcal.methods.abbe.dataset"),
    ("rtcal.store.dataset", "abbe_conditions", "rtcal.methods.abbe.dataset"),
    ("rtcal.store.dataset", "summarise_conditions", "rtcal.methods.conditions"),
    ("rtcal.engine.checks", "EncoderCheck", "rtcal.methods.abbe.checks"),
    ("rtcal.engine.operator", "reseat_instruction", "rtcal.methods.abbe.plan"),
    ("rtcal.engine.operator", "tracer_instruction", "rtcal.methods.multistation.plan"),
    ("rtcal.procedure.loader", "load_scenario", "simulators.scenario_file"),
    ("rtcal.procedure.loader", "scenario_schema", "simulators.scenario_file"),
    ("rtcal.results.model", "AbbeEstimator", "rtcal.methods.abbe.results"),
    ("rtcal.results.model", "MultistationEstimator", "rtcal.methods.multistation.results"),
]


@pytest.mark.parametrize("old, name, new", MOVED, ids=[f"{o}.{n}" for o, n, _ in MOVED])
def test_a_moved_name_still_works_for_one_release_and_says_where_it_went(old, name, new):
    with pytest.warns(DeprecationWarning, match=f"{new}.{name}"):
        found = getattr(importlib.import_module(old), name)
    assert found is getattr(importlib.import_module(new), name)


def test_the_seed_methods_take_from_the_face_what_it_serves():
    """A seed method's folder imports a name from where rtcal.api takes it only when the face does not serve every
    name of that import (its solvers, its simulation, its own results blocks): what the face serves, it takes from
    the face, as a plugin does."""
    where = api._WHERE
    around = []
    for path in sorted((REPO / "rtcal" / "methods").glob("*/*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module in where and all(a.name in where[node.module]
                                                                                 for a in node.names):
                around.append(f"{path.relative_to(REPO)}:{node.lineno} from {node.module}")
    assert not around, around


def test_the_certificates_roles_moved_into_the_methods():
    from rtcal.methods import METHODS

    with pytest.warns(DeprecationWarning, match="instrument_roles"):
        from rtcal.deliverables.certificate import ROLES  # noqa: F401
    roles = METHODS["encoder_abbe_error"].instrument_roles
    assert callable(roles)


@pytest.mark.slow
def test_mypy_strict_checks_the_sample_plugins_against_the_installed_rtcal(tmp_path):
    """rtcal built as its wheel would install it (setuptools' build_py: its packages and their package-data) into a
    fresh venv's site-packages; the sample plugins, copied out of the checkout as a plugin's author has them, pass
    ``mypy --strict`` there — and without rtcal's py.typed they do not (mypy then knows nothing of rtcal.api)."""
    lib = tmp_path / "lib"
    built = subprocess.run([sys.executable, "-c", "import sys, setuptools; sys.argv = ['setup.py', '-q', 'build_py', "
                            f"'--build-lib', {str(lib)!r}]; setuptools.setup()"], cwd=REPO, capture_output=True, text=True,
                           timeout=300)
    assert built.returncode == 0, built.stderr
    assert (lib / "rtcal" / "py.typed").exists() and (lib / "drivers" / "py.typed").exists()
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp_path / "venv")], check=True, timeout=60)
    python = tmp_path / "venv" / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    for package in PROJECT:
        shutil.copytree(lib / package, site / package)
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # pydantic, numpy, matplotlib
    src = tmp_path / "src"
    src.mkdir()
    for module in sorted((REPO / "tests" / "plugins").glob("*/rtcal_*.py")):
        shutil.copy(module, src)
    (tmp_path / "mypy.ini").write_text("[mypy]\nstrict = True\nplugins = pydantic.mypy\n")

    def mypy() -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(tmp_path / "mypy.ini"), "--cache-dir",
                               str(tmp_path / "cache"), "--python-executable", str(python), *map(str, sorted(src.glob("*.py")))],
                              capture_output=True, text=True, timeout=600, cwd=tmp_path)

    checked = mypy()
    assert checked.returncode == 0 and "no issues found in 5 source files" in checked.stdout, checked.stdout + checked.stderr
    (site / "rtcal" / "py.typed").unlink()
    untyped = mypy()
    assert untyped.returncode == 1 and 'Class cannot subclass "MethodBase" (has type "Any")' in untyped.stdout, untyped.stdout
