"""Layering: cli -> daemon -> tasks -> controller -> drivers -> common; tasks hold the
controller's task port, never its service; the bottom layer imports nothing of ours; the
simulator stands beside the drivers and only the sim driver's adapter imports it; the client
knows only the shared vocabulary; the product never imports the studies
(docs/architecture.md, decision 1). Every import of ours names ``fluidsense``.

(Its tests with real peers: tests/system/test_layering.py.)
"""

from __future__ import annotations

import ast

from support.harness import REPO

# the folders of the package (the repository's root is ``fluidsense``) and of the studies
PARTS = ("cli", "client", "common", "config", "controller", "daemon", "drivers", "simulator", "tasks")


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
