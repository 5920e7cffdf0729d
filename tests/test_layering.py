"""Layering: cli -> daemon -> tasks -> controller -> drivers -> common; tasks hold the
controller's task port, never its service; the bottom layer imports nothing of ours; the
simulator stands beside the drivers and only the sim driver's adapter imports it; the client
knows only the shared vocabulary; the product never imports the studies
(docs/architecture.md, decision 1). Every import of ours names ``fluidsense``."""

from __future__ import annotations

import ast
import subprocess
import sys

from support.harness import REPO

# the folders of the package (the repository's root is ``fluidsense``) and of the studies
PARTS = ("cli", "client", "common", "config", "controller", "daemon", "drivers", "simulator", "tasks")


def test_import_contracts_hold():
    run_linter = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    out = subprocess.run([sys.executable, "-c", run_linter, "--no-cache"], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert "7 kept, 0 broken" in out.stdout, out.stdout + out.stderr
    assert out.returncode == 0


def test_every_import_of_ours_goes_through_the_one_namespace():
    """In a checkout the folders are importable by their bare names too (the working
    directory is on the path); installed, only ``fluidsense.*`` exists. An import of a bare
    part name would pass here and fail in the wheel, so none may exist."""
    files = [p for part in (*PARTS, "lab", "tests", "examples") for p in (REPO / part).rglob("*.py")]
    files += [REPO / "__init__.py", REPO / "__main__.py"]
    bad = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module else []
            bad += [f"{path.relative_to(REPO)}:{node.lineno}: {n}" for n in names if n.split(".")[0] in PARTS]
    assert len(files) > 200 and not bad, bad


def test_controller_and_tasks_do_not_load_the_plant_or_ur_rtde_at_import():
    code = ("import sys, fluidsense.controller.service, fluidsense.controller.requests.server, "
            "fluidsense.tasks.size_survey, fluidsense.cli;"
            "bad = [m for m in sys.modules if m.startswith(('fluidsense.drivers.sim', 'fluidsense.simulator', 'rtde'))];"
            "print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


def test_no_import_circle_in_the_package():
    """No module of the product imports, through any chain, a module that imports it back
    (the request layer once did: service <-> dispatch, gripper, status). The graph is
    import-linter's own (grimp), TYPE_CHECKING imports included; the studies are left out."""
    import grimp

    graph = grimp.build_graph("fluidsense")
    ours = {m for m in graph.modules if not m.startswith("fluidsense.lab")}
    circles = [(a, b) for a in ours for b in graph.find_modules_directly_imported_by(a)
               if b in ours and b != a and graph.chain_exists(importer=b, imported=a)]
    assert len(ours) > 150 and not circles, circles[:5]
