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


# What the seed methods' folders still take from inside rtcal (neither rtcal.api nor rtcal.solvers nor their own
# folder): (folder, module) → (file, names). Why each stays is in the folder's __init__ docstring; a new one fails
# test_the_seed_methods_take_from_inside_only_what_is_listed until it comes from the face or is listed with its reason.
SEED_INTERNAL = {
    ("multistation", "drivers"): {"method.py": {"factory"}},  # typed openers: limits, volume, tool
    ("multistation", "rtcal.results"): {"method.py": {"model"}},  # rm: its estimate blocks
    ("multistation", "rtcal.results.model"): {  # its estimate blocks, in the shared model
        "outputs.py": {"AXIS_CONVENTION", "NetworkEstimate", "PaperEstimate", "StationChainEstimate"},
        "results.py": {"AxisLocation", "ErrorMotionTarget", "NetworkEstimate", "PaperEstimate", "SharedDeadPathEstimate"}},
    ("multistation", "rtcal.deliverables.certificate"): {"outputs.py": {"largest"}},
    ("multistation", "simulators.bench"): {"method.py": {"Bench"}},  # its own simulation on rtcal's bench
    ("multistation", "simulators.instruments"): {"method.py": {"SimCmm", "SimEnvironmentSensor", "SimLaserTracer",
                                                               "SimStage"}},
    ("multistation", "simulators.scenario"): {"method.py": {"AngularHarmonic", "CmmFieldTerm", "EnvironmentScenario",
                                                            "LinearHarmonic", "SphereLobe"}},  # the Monte Carlo's draws
    ("multistation", "simulators.truth"): {"method.py": {"station_truth"}},
    # rtcal plan --optimize's design of CMM points: a command's work (a run's store in, a procedure's YAML out)
    ("multistation", "rtcal.methods.planner"): {"design.py": {"keep_bench"}},
    ("multistation", "rtcal.outputs"): {"design.py": {"write_output"}},
    ("multistation", "rtcal.procedure.yamlfile"): {"design.py": {"load_yaml", "read_text"}},
    ("multistation", "rtcal.store.runstore"): {"design.py": {"RunStore"}},
    ("multistation", "rtcal.units"): {"design.py": {"ARCSEC_PER_RAD"}},
    ("abbe", "drivers"): {"method.py": {"factory"}},
    ("abbe", "rtcal.results"): {"method.py": {"model"}},
    ("abbe", "rtcal.results.model"): {"outputs.py": {"AbbeEstimate", "HarmonicTerm", "PeriodicError", "PeriodicTerm"},
                                      "results.py": {"AbbeEstimate"}},
    ("abbe", "rtcal.deliverables.certificate"): {"outputs.py": {"largest", "period_text", "smallest"}},
    ("abbe", "simulators.bench"): {"method.py": {"Bench"}},
    ("abbe", "simulators.instruments"): {"method.py": {"SimAutocollimator", "SimDialIndicator", "SimEncoder",
                                                       "SimEnvironmentSensor", "SimStage"}},
    ("abbe", "simulators.truth"): {"method.py": {"abbe_truth"}},
}


def seed_internal_imports(folder: Path) -> dict[tuple[str, str], dict[str, set[str]]]:
    """Every import of rtcal, drivers or simulators in a method's folder that is not rtcal.api, rtcal.solvers or the
    folder itself: (folder, module) → file → names (``import x.y`` counted as module x.y, name ``*``)."""
    own = f"rtcal.methods.{folder.name}"
    found: dict[tuple[str, str], dict[str, set[str]]] = {}
    for path in sorted(folder.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module:
                taken = [(node.module, a.name) for a in node.names]
            elif isinstance(node, ast.Import):
                taken = [(a.name, "*") for a in node.names]
            else:
                continue
            for module, name in taken:
                if module.split(".")[0] not in PROJECT or module == "rtcal.api" or module == "rtcal.solvers" \
                        or module.startswith(("rtcal.solvers.", own + ".")) or module == own:
                    continue
                found.setdefault((folder.name, module), {}).setdefault(path.name, set()).add(name)
    return found


def test_the_seed_methods_take_from_inside_only_what_is_listed():
    """Issue 41 item 1: the seed folders take rtcal through the face as far as their own solvers and simulation
    allow; what they still take from inside is the explicit list above, each entry with its reason."""
    found: dict[tuple[str, str], dict[str, set[str]]] = {}
    for folder in ("multistation", "abbe"):
        found.update(seed_internal_imports(REPO / "rtcal" / "methods" / folder))
    new = []
    for (f, m), files in sorted(found.items()):
        for file, names in sorted(files.items()):
            unlisted = names - SEED_INTERNAL.get((f, m), {}).get(file, set())
            if unlisted:
                new.append(f"rtcal/methods/{f}/{file}: from {m} import {', '.join(sorted(unlisted))}")
    assert not new, ("take these from rtcal.api (add a name to the face where a plugin would need it too), or list "
                     f"them in SEED_INTERNAL with why (the folder's __init__): {new}")
    assert found == SEED_INTERNAL, "an import listed in SEED_INTERNAL is gone: take it off the list"


def test_the_internal_imports_check_sees_a_new_one(tmp_path):
    """The check above reads every form of import: one more from inside is found, one through the face is not."""
    folder = tmp_path / "abbe"
    folder.mkdir()
    (folder / "x.py").write_text("from rtcal.api import Move\nfrom rtcal.solvers.abbe import AbbeVisits\n"
                                 "from rtcal.methods.abbe.plan import AbbePlan\nimport rtcal.engine.walk\n"
                                 "def f():\n    from rtcal.engine.checks import arrive\n")
    assert seed_internal_imports(folder) == {("abbe", "rtcal.engine.walk"): {"x.py": {"*"}},
                                             ("abbe", "rtcal.engine.checks"): {"x.py": {"arrive"}}}


def test_recover_imports_for_one_release_and_says_what_replaced_it():
    """The sample method of the commit before the method-folder move imported ``Recover`` from rtcal.engine.steps
    (removed with redo, no plan yields it): the name imports again for one release, its warning naming what replaced
    it — the instrument's fault policy, which recovers the device before each retry, and a Read's check."""
    import warnings

    import rtcal.engine.steps as steps

    with pytest.warns(DeprecationWarning, match=r"steps\.Recover was removed: .*fault policy.*recover\(\).*Read's check"):
        from rtcal.engine.steps import Recover
    assert Recover("stage").instrument == "stage" and Recover.__name__ == "Recover"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the other names of the module warn of nothing
        assert steps.Move("stage", 1.0).target == 1.0
    with pytest.raises(AttributeError, match="no attribute 'Redo'"):
        steps.Redo  # noqa: B018


def test_a_plan_that_yields_the_old_recover_stops_as_failed_naming_the_steps_it_knows():
    """The stand-in only imports: the engine executes no Recover; a plan that still yields one is a failed run with
    an event, as any step the engine does not know is (tests/test_plan_contracts.py)."""
    from rtcal.engine.engine import PlanError
    from rtcal.procedure.models import FaultPolicy
    from tests.test_engine import TwoDevicePlan, run_plan

    with pytest.warns(DeprecationWarning):
        from rtcal.engine.steps import Recover

    class OldPlan(TwoDevicePlan):
        def attempt(self, entry):
            yield Recover("stage")

    stored, error, readings, events, stage, engine, docs = run_plan(OldPlan([0.0], FaultPolicy()))
    assert isinstance(error, PlanError) and "Recover is not a step the engine knows" in str(error)
    assert engine.state == "failed" and events[-1]["kind"] == "abort"


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
