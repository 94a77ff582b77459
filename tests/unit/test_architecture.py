"""espdock's folders are its layers: no import cycle, and no module imports a higher layer.

The graph is read with ast from the source tree (tests/architecture.py), deferred imports
inside functions included, so a cycle cannot hide behind a function-level import.
"""

from tests.architecture import cycles, import_graph, layer, modules, upward


def test_every_module_is_in_a_layer():
    unplaced = []
    for name in modules():
        try:
            layer(name)
        except LookupError:
            unplaced.append(name)
    assert unplaced == [], f"add these to a layer in tests/architecture.py: {unplaced}"


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_no_module_imports_a_higher_layer_or_the_other_world():
    assert upward(import_graph()) == []


def test_the_graph_sees_deferred_and_package_relative_imports(tmp_path):
    package = tmp_path / "espdock"
    (package / "low").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "low" / "__init__.py").write_text("")
    (package / "low" / "a.py").write_text("def f():\n    from espdock.high import b\n")
    (package / "high.py").write_text("from espdock.low import a\n")
    graph = import_graph(package)
    assert graph["espdock.low.a"] == {"espdock.high"}
    assert graph["espdock.high"] == {"espdock.low.a"}
    assert cycles(graph) == [["espdock.high", "espdock.low.a"]]


def test_what_the_engine_is_asked_is_pure_data_and_translation():
    # images/specs.py is read and tested without an engine: it may not reach one.
    talks = {"espdock.images.engine", "espdock.images.local_api", "espdock.images.sdk"}
    assert import_graph()["espdock.images.specs"] & talks == set()
