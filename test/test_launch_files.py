"""Launch files, parameter file and node parameter tables agree (no ROS needed)."""

from __future__ import annotations

import ast
import dataclasses
import importlib
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bldc_propulsion.nodes import params as P

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch"
CONFIG = ROOT / "config" / "propulsion.yaml"
NODES = ROOT / "bldc_propulsion" / "nodes"
NODE_SOURCES = {
    P.BATTERY_FILTER: NODES / "battery_filter_node.py",
    P.TACHOMETER: NODES / "tachometer_node.py",
    P.THRUST_ESTIMATOR: NODES / "thrust_estimator_node.py",
}
CORE_CONFIGS = {
    P.BATTERY_FILTER: ("bldc_propulsion.core.battery_filter", "BatteryFilterConfig"),
    P.TACHOMETER: ("bldc_propulsion.core.tachometer", "TachometerConfig"),
}


def load_yaml(path: Path):
    try:
        import yaml
    except ImportError:  # PyYAML is on every ROS machine; ruamel.yaml in the plain venv
        from ruamel.yaml import YAML

        return YAML(typ="safe", pure=True).load(path.read_text())
    return yaml.safe_load(path.read_text())


def launch_arguments(path: Path) -> dict[str, str | None]:
    """DeclareLaunchArgument(name, default_value=...) calls: {name: literal default or None}."""
    out: dict[str, str | None] = {}
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument":
            name = node.args[0].value
            default = next((k.value for k in node.keywords if k.arg == "default_value"), None)
            out[name] = default.value if isinstance(default, ast.Constant) else None
    return out


def test_launch_files_parse_and_define_generate_launch_description():
    for path in (LAUNCH / "propulsion.launch.py", LAUNCH / "quadrotor.launch.py"):
        tree = ast.parse(path.read_text(), str(path))
        names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert "generate_launch_description" in names, path


def test_single_motor_launch_arguments():
    args = launch_arguments(LAUNCH / "propulsion.launch.py")
    assert set(args) == {"namespace", "use_sim_time", "params_file", "model", "single_process"}
    assert args["namespace"] == ""  # root names: `ros2 bag play BENCH_BAG --clock` feeds it
    assert args["use_sim_time"] == "false"
    assert args["model"] == ""
    assert args["single_process"] == "false"
    assert args["params_file"] is None  # the installed config/propulsion.yaml (substitution)


def test_quadrotor_launch_arguments_and_motor_namespaces():
    args = launch_arguments(LAUNCH / "quadrotor.launch.py")
    assert set(args) == {"motors", "use_sim_time", "params_file", "model", "single_process"}
    assert args["motors"] == "4"
    source = (LAUNCH / "quadrotor.launch.py").read_text()
    assert "propulsion_all" in source
    # one pack: one battery filter at the root, every estimator reads /battery/voltage
    assert source.count("executable='battery_filter'") == 1
    assert "('battery/voltage', '/battery/voltage')" in source
    assert P.namespaces(4) == ["motor0", "motor1", "motor2", "motor3"]


def test_quadrotor_launch_refuses_a_bad_motor_count_in_one_line():
    """motor_count() is plain Python: load it without launch/launch_ros."""
    tree = ast.parse((LAUNCH / "quadrotor.launch.py").read_text())
    fn = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "motor_count")
    scope = {"MAX_MOTORS": 16}
    exec(compile(ast.Module(body=[fn], type_ignores=[]), "quadrotor.launch.py", "exec"), scope)
    assert scope["motor_count"]("4") == 4
    for bad in ("0", "17", "four", "-1", ""):
        with pytest.raises(ValueError, match="motors must be an integer in 1..16") as e:
            scope["motor_count"](bad)
        assert "\n" not in str(e.value)


def test_every_launched_node_shuts_the_launch_down_when_it_exits():
    for name in ("propulsion.launch.py", "quadrotor.launch.py"):
        source = (LAUNCH / name).read_text()
        tree = ast.parse(source)
        calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
                 and getattr(n.func, "id", "") == "Node"]
        assert calls, name
        for call in calls:
            assert any(k.arg == "on_exit" for k in call.keywords), f"{name}: a Node without on_exit"


def test_launch_files_start_the_entry_points_setup_py_installs():
    setup = (ROOT / "setup.py").read_text()
    for name in (*P.NODE_NAMES, "propulsion_all"):
        assert f'"{name}"' in setup, f"setup.py has no entry point {name}"
    source = (LAUNCH / "propulsion.launch.py").read_text()
    for name in P.NODE_NAMES:
        assert f"'{name}'" in source


def test_parameter_file_uses_wildcard_namespace_and_node_names():
    data = load_yaml(CONFIG)
    # "/**/<node>": that node in any namespace, root or /motor0.. /motor3 (rcl wildcards)
    assert set(data) == {f"/**/{node}" for node in P.NODE_NAMES}
    for node in P.NODE_NAMES:
        assert list(data[f"/**/{node}"]) == ["ros__parameters"]


@pytest.mark.parametrize("node", P.NODE_NAMES)
def test_parameter_file_matches_node_tables(node):
    given = load_yaml(CONFIG)[f"/**/{node}"]["ros__parameters"]
    table = {p.name: p for p in P.NODE_PARAMS[node]}
    assert set(given) == set(table), f"{node}: yaml and declared parameters differ"
    for name, value in given.items():
        p = table[name]
        # rclpy refuses an int for a double parameter (and vice versa): types must be exact
        assert type(value) is type(p.default), f"{node}.{name}: {value!r} vs {p.default!r}"
        assert value == p.default, f"{node}.{name}: yaml {value!r}, node default {p.default!r}"
        if p.min is not None:
            assert p.min <= value <= p.max


@pytest.mark.parametrize("node", P.NODE_NAMES)
def test_every_node_declares_its_table_and_nothing_else(node):
    source = NODE_SOURCES[node].read_text()
    tree = ast.parse(source, str(NODE_SOURCES[node]))
    assert "declare_parameters(self, " in source
    assert not any(
        isinstance(n, ast.Attribute) and n.attr == "declare_parameter" for n in ast.walk(tree)
    ), "parameters are declared from the table only"
    table_name = {P.BATTERY_FILTER: "BATTERY_FILTER_PARAMS", P.TACHOMETER: "TACHOMETER_PARAMS",
                  P.THRUST_ESTIMATOR: "THRUST_ESTIMATOR_PARAMS"}[node]
    assert f"declare_parameters(self, {table_name})" in source


@pytest.mark.parametrize("node", sorted(CORE_CONFIGS))
def test_core_parameters_are_core_config_fields_with_the_same_defaults(node):
    module_name, class_name = CORE_CONFIGS[node]
    try:
        config_class = getattr(importlib.import_module(module_name), class_name)
    except ImportError as e:  # pragma: no cover - the core is written alongside
        pytest.skip(f"{module_name} not importable: {e}")
    fields = {f.name for f in dataclasses.fields(config_class)}
    defaults = config_class()
    for p in P.NODE_PARAMS[node]:
        if not p.core:
            continue
        assert p.name in fields, f"{class_name} has no field {p.name}"
        assert getattr(defaults, p.name) == pytest.approx(p.default), p.name


def test_tables_are_consistent():
    for table in P.NODE_PARAMS.values():
        P.check_table(table)
        names = [p.name for p in table]
        assert len(names) == len(set(names))
        assert all(p.description for p in table)
    with pytest.raises(ValueError):
        P.check_table((P.Param("x", 5.0, "d", 0.0, 1.0),))
    with pytest.raises(ValueError):
        P.check_table((P.Param("x", 5, "d", 0.0, 10.0),))


def test_core_kwargs_keeps_only_core_parameters():
    values = {p.name: p.default for p in P.BATTERY_FILTER_PARAMS}
    kwargs = P.core_kwargs(P.BATTERY_FILTER_PARAMS, values)
    assert "publish_rate_hz" not in kwargs and "queue_depth" not in kwargs
    assert kwargs["divider_ratio"] == 1.999


def test_level_byte_is_the_diagnostic_byte_field():
    assert P.level_byte(0) == b"\x00"
    assert P.level_byte(1) == b"\x01"
    assert P.level_byte(2) == b"\x02"
    assert P.level_byte(7) == b"\x03"  # clamped to STALE
    assert isinstance(P.level_byte(1), bytes) and len(P.level_byte(1)) == 1


def test_stamp_round_trip():
    for t in (0.0, 1.5, 1234567.000000001, 1e-9, 2.999999999):
        sec, nanosec = P.seconds_to_stamp(t)
        assert 0 <= nanosec < 1_000_000_000
        assert P.stamp_to_seconds(sec, nanosec) == pytest.approx(t, abs=1e-9)
    assert P.seconds_to_stamp(2.9999999999) == (3, 0)


def test_plain_helpers():
    assert P.diagnostic_name("/motor0/tachometer", "signal") == "motor0/tachometer: signal"
    assert P.key_values({"rejected": "3", "n": 4}) == [("rejected", "3"), ("n", "4")]
    assert math.isnan(P.finite_or_nan(float("inf")))
    assert P.finite_or_nan(2) == 2.0
    assert P.namespaces(1) == [""]
    with pytest.raises(ValueError):
        P.namespaces(0)


def test_node_package_imports_without_rclpy():
    code = ("import sys, bldc_propulsion.nodes, bldc_propulsion.nodes.params; "
            "sys.exit('rclpy' in sys.modules)")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})


def test_node_sources_compile():
    for path in sorted(NODES.glob("*.py")):
        compile(path.read_text(), str(path), "exec")


# --- the launch files built with a stand-in for launch/launch_ros (not on PyPI) ---------------

class _Recorded:
    """A stand-in launch class: keeps its positional and keyword arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _stub_modules() -> dict:
    """launch, launch.actions, ... with every name the launch files import as a _Recorded."""
    import types

    names = {
        "launch": ["LaunchDescription"],
        "launch.actions": ["DeclareLaunchArgument", "OpaqueFunction", "RegisterEventHandler",
                           "Shutdown", "EmitEvent"],
        "launch.event_handlers": ["OnProcessIO", "OnProcessExit"],
        "launch.substitutions": ["LaunchConfiguration", "PathJoinSubstitution"],
        "launch_ros.actions": ["Node"],
        "launch_ros.parameter_descriptions": ["ParameterValue"],
        "launch_ros.substitutions": ["FindPackageShare"],
    }
    modules = {"launch_ros": types.ModuleType("launch_ros")}
    for module, classes in names.items():
        m = modules.setdefault(module, types.ModuleType(module))
        for cls in classes:
            setattr(m, cls, type(cls, (_Recorded,), {}))
    return modules


def _build(path: Path, monkeypatch, configuration: dict[str, str]) -> list:
    """The entities the launch file's OpaqueFunction returns for these argument values."""
    for name, module in _stub_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    LaunchConfiguration = sys.modules["launch.substitutions"].LaunchConfiguration
    LaunchConfiguration.perform = lambda self, context: context[self.args[0]]
    scope = {"__name__": "launch_file", "__file__": str(path)}
    exec(compile(path.read_text(), str(path), "exec"), scope)
    description = scope["generate_launch_description"]()
    entities = description.args[0]
    declared = {e.args[0]: e.kwargs.get("default_value") for e in entities
                if type(e).__name__ == "DeclareLaunchArgument"}
    values = {k: v if isinstance(v, str) else "" for k, v in declared.items()}
    values.update(configuration)
    (opaque,) = [e for e in entities if type(e).__name__ == "OpaqueFunction"]
    return opaque.kwargs["function"](values)


@pytest.mark.parametrize("path,configuration,executables", [
    (LAUNCH / "propulsion.launch.py", {}, ["battery_filter", "tachometer", "thrust_estimator"]),
    (LAUNCH / "propulsion.launch.py", {"single_process": "true", "model": "/m.npz"},
     ["propulsion_all"]),
    (LAUNCH / "quadrotor.launch.py", {},
     ["battery_filter"] + ["tachometer", "thrust_estimator"] * 4),
    (LAUNCH / "quadrotor.launch.py", {"motors": "2"},
     ["battery_filter"] + ["tachometer", "thrust_estimator"] * 2),
    (LAUNCH / "quadrotor.launch.py", {"single_process": "true"}, ["propulsion_all"]),
])
def test_every_node_reports_its_exit_to_one_watch_that_reads_stderr(
        monkeypatch, path, configuration, executables):
    """Every Node's on_exit is the LaunchWatch whose on_stderr an OnProcessIO handler feeds,
    registered before the nodes start (a node's last stderr line says why it exited)."""
    from bldc_propulsion.nodes.launch_watch import LaunchWatch

    entities = _build(path, monkeypatch, configuration)
    register = entities[0]
    assert type(register).__name__ == "RegisterEventHandler"
    (io_handler,) = register.args
    assert type(io_handler).__name__ == "OnProcessIO"
    watch = io_handler.kwargs["on_stderr"].__self__
    assert isinstance(watch, LaunchWatch)
    nodes = entities[1:]
    assert [n.kwargs["executable"] for n in nodes] == executables
    for node in nodes:
        assert type(node).__name__ == "Node"
        on_exit = node.kwargs["on_exit"]
        assert on_exit.__self__ is watch and on_exit.__func__ is LaunchWatch.on_exit
    if configuration.get("motors") == "2":
        assert [n.kwargs.get("namespace") for n in nodes[1:]] == ["motor0"] * 2 + ["motor1"] * 2
        # each rotor its own joint and frame, after the parameter file (which sets 'rotor' for all)
        for node in nodes[1:]:
            ns, given = node.kwargs["namespace"], node.kwargs["parameters"]
            if node.kwargs["executable"] == "tachometer":
                assert given[-1] == {"joint_name": f"{ns}_rotor"}
            else:
                assert given[-2:] == [{"joint_name": f"{ns}_rotor"}, {"frame_id": f"{ns}_rotor"}]


def _exited(returncode: int, name: str = "thrust_estimator-3", pid: int = 4242,
            node_name: str | None = "/motor1/thrust_estimator"):
    import types

    action = types.SimpleNamespace(node_name=node_name,
                                   is_node_name_fully_specified=lambda: node_name is not None)
    return types.SimpleNamespace(returncode=returncode, process_name=name, pid=pid,
                                 action=action)


def _stderr(text: bytes, name: str = "thrust_estimator-3"):
    import types

    return types.SimpleNamespace(text=text, process_name=name)


def _context(shutting_down: bool):
    import types

    return types.SimpleNamespace(is_shutdown=shutting_down)


def test_a_node_that_refuses_its_model_ends_the_launch_naming_it_and_why():
    from bldc_propulsion.nodes.launch_watch import LaunchWatch, NodeLost

    watch = LaunchWatch()
    watch.on_stderr(_stderr(b"[INFO] [thrust_estimator]: starting\n"))
    watch.on_stderr(_stderr(b"thrust_estimator: model /m.npz: not a model file (no 'kind')\n\n"))
    watch.on_stderr(_stderr(b"battery ok\n", name="battery_filter-1"))  # another process
    with pytest.raises(NodeLost) as e:
        watch.on_exit(_exited(2), _context(shutting_down=False))
    message = str(e.value)
    assert message == ("node thrust_estimator-3 /motor1/thrust_estimator (pid 4242) exited with "
                       "status 2 while the launch was running: thrust_estimator: model /m.npz: "
                       "not a model file (no 'kind'); shutting the launch down, exit status 1")
    assert "\n" not in message


def test_a_crash_during_shutdown_still_fails_the_launch_and_a_clean_stop_does_not():
    from bldc_propulsion.nodes.launch_watch import LaunchWatch, NodeLost

    watch = LaunchWatch()
    assert watch.on_exit(_exited(0), _context(shutting_down=True)) is None  # Ctrl-C: stopped
    with pytest.raises(NodeLost, match=r"killed by SIGSEGV \(nothing on stderr\)"):
        watch.on_exit(_exited(-11), _context(shutting_down=True))
    with pytest.raises(NodeLost, match="killed by SIGKILL"):  # launch's escalation
        watch.on_exit(_exited(-9, node_name=None, name="propulsion_all-1"), _context(True))
    with pytest.raises(NodeLost, match=r"^node propulsion_all-1 \(pid 4242\) exited with status 0 "
                                       "while the launch was running"):
        watch.on_exit(_exited(0, node_name=None, name="propulsion_all-1"), _context(False))
    with pytest.raises(NodeLost, match="status 1 while the launch was running: "
                                       "RuntimeError: boom"):
        watch.on_stderr(_stderr(b"Traceback (most recent call last):\n  File x\nRuntimeError: boom\n"))
        watch.on_exit(_exited(1), _context(False))
