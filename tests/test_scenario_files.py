"""`trustnav drive PATH.toml`: any scenario file, camera / control / CARLA options on the command line,
clear errors naming the bad input (issue 21, item 4)."""

from __future__ import annotations

import json

import pytest

from trustnav.cli import main
from trustnav.sim.driving import load_drive_scenario
from trustnav.sim.driving.world import CarlaRouteSpec

MINIMAL = """
name = "by-the-lane"
title = "one distracted pedestrian beside the lane"
ego_start = [33.5, 129.0]
goal = [33.5, 100.0]
duration = 7.0

[[pedestrian]]
name = "texter"
position = [37.0, 112.0]
attentive = false
pose = "distracted"
body_yaw_deg = 180.0
look_at_camera = false
"""


def _run(argv: list[str], capsys) -> tuple[int, str, str]:  # type: ignore[no-untyped-def]
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_minimal_file_loads_with_every_section_optional(tmp_path):
    path = tmp_path / "minimal.toml"
    path.write_text(MINIMAL)
    sc = load_drive_scenario(path)
    assert sc.name == "by-the-lane" and sc.carla == CarlaRouteSpec() and sc.carla.options() == {}
    # the presets still load unchanged, by name and as files
    for name in ("case-1", "case-2"):
        preset = load_drive_scenario(name)
        assert preset.carla == CarlaRouteSpec()
        text = load_drive_scenario.__globals__["resources"].files("trustnav.sim") / f"scenarios/{name}.toml"
        copy = tmp_path / f"{name}-copy.toml"
        copy.write_text(text.read_text())
        assert load_drive_scenario(copy) == preset


def test_the_carla_section_is_validated_and_passed_as_options(tmp_path):
    path = tmp_path / "carla.toml"
    path.write_text(MINIMAL + '\n[carla]\ntown = "Town03"\nfov_deg = 45.0\ndistracted_walker = 8\n')
    sc = load_drive_scenario(path)
    assert sc.carla.options() == {"town": "Town03", "fov_deg": 45.0, "distracted_walker": 8}
    path.write_text(MINIMAL + "\n[carla]\nfov_deg = 400.0\n")
    with pytest.raises(ValueError, match="fov_deg"):
        load_drive_scenario(path)
    path.write_text(MINIMAL + '\n[carla]\nweather = "rain"\n')
    with pytest.raises(ValueError, match=r"unknown key 'weather' in \[carla\]"):
        load_drive_scenario(path)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "does not exist"),
        ("name = 'x'\n[road\n", "not valid TOML"),
        (MINIMAL.replace("duration = 7.0", "duration = 7.0\nspeed_limit = 3"), "speed_limit"),
        (MINIMAL + "\n[control.gamma]\ngamma_ini = 0.1\nrho = 2\n", "rho"),
        (MINIMAL + "\n[road]\nlane_width = -1\n", "lane_width"),
        (MINIMAL + "\n[camera]\nfov_deg = 'wide'\n", "fov_deg in [camera] of {path} must be a number, got 'wide'"),
        (MINIMAL.replace("duration = 7.0", "duration = 'long'"), "duration in {path} must be a number > 0 s"),
        (
            MINIMAL.replace("duration = 7.0", "duration = 7.0\nduraton = 7"),
            "unknown key 'duraton' in {path}: did you mean 'duration'?",
        ),
        (MINIMAL + "\n[control]\nhorizn = 5\n", "unknown key 'horizn' in [control] of {path}: did you mean 'horizon'?"),
        (
            MINIMAL.replace("pose =", "postion = [0, 1]\npose ="),
            "unknown key 'postion' in pedestrian 'texter' of {path}: did you mean 'position'?",
        ),
    ],
)
def test_bad_files_are_refused_naming_the_file_and_the_key(tmp_path, capsys, content, expected):
    path = tmp_path / "scenario.toml"
    if content is not None:
        path.write_text(content)
    code, out, err = _run(["drive", str(path), "--sensing", "keypoints", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and str(path) in err and expected.format(path=path) in err, err
    assert not (tmp_path / "o").exists()


def test_every_error_of_a_file_is_one_line_naming_file_section_and_key(tmp_path, capsys):
    path = tmp_path / "kerb-gap.toml"
    path.write_text(MINIMAL + "\n[control]\nhorizn = 5\ndt = 'fast'\n[road]\nlanes = 1.5\n")
    code, out, err = _run(["drive", str(path), "--sensing", "keypoints", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and out == ""
    assert err.splitlines() == [
        f"trustnav: error: unknown key 'horizn' in [control] of {path}: did you mean 'horizon'?",
        f"trustnav: error: dt in [control] of {path} must be a number > 0 s, got 'fast'",
        f"trustnav: error: lanes in [road] of {path} must be an integer >= 1, got 1.5",
    ]


def test_a_folder_and_a_paper_scenario_are_refused(tmp_path, capsys):
    code, _, err = _run(["drive", str(tmp_path), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "is a folder" in err
    paper = load_drive_scenario.__globals__["resources"].files("trustnav.sim") / "scenarios/paper-1.toml"
    code, _, err = _run(["drive", str(paper), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "trustnav scenario" in err


def test_drive_runs_a_scenario_file_with_command_line_options(tmp_path, capsys):
    path = tmp_path / "minimal.toml"
    path.write_text(MINIMAL)
    out = tmp_path / "o"
    argv = ["drive", str(path), "--sensing", "keypoints", "--no-video", "--out", str(out), "--safety-radius", "2.0",
            "--horizon", "5", "--fov", "80", "--camera-height", "1.5", "--duration", "6"]  # fmt: skip
    code, printed, _ = _run(argv, capsys)
    assert code == 0, printed
    m = json.loads((out / "metrics.json").read_text())
    assert m["scenario"] == "by-the-lane" and [p["name"] for p in m["pedestrians"]] == ["texter"]
    assert m["safety_radius"] == 2.0
    assert m["pedestrians"][0]["min_distance"] >= 2.0 - 0.05
    assert "drive by-the-lane" in printed


@pytest.mark.parametrize(
    ("extra", "expected"),
    [(["--fov", "300"], "--fov must be in [10, 170] degrees, got 300"),
     (["--horizon", "0"], "--horizon must be an integer in [1, 100] steps, got 0"),
     (["--safety-radius", "-1"], "--safety-radius must be in (0, 20] m, got -1"),
     (["--town", "Town03"], "need --world carla")],
)  # fmt: skip
def test_bad_options_are_refused_naming_the_option(tmp_path, capsys, extra, expected):
    code, _, err = _run(["drive", "case-1", "--out", str(tmp_path / "o"), *extra], capsys)
    assert code == 2 and expected in err, err


def test_carla_route_options_reach_the_bridge(tmp_path, capsys, monkeypatch):
    """The scenario's [carla] section, overridden by the command line, is what the bridge gets."""
    import trustnav.carla_bridge.command as command

    seen = {}

    def fake_runner(args, route=None):  # type: ignore[no-untyped-def]
        seen.update(route or {})
        raise command.CarlaCommandError("stop here", 2)

    monkeypatch.setattr(command, "carla_runner", fake_runner)
    path = tmp_path / "carla.toml"
    path.write_text(MINIMAL + '\n[carla]\ntown = "Town03"\nfov_deg = 45.0\n')
    argv = ["drive", str(path), "--world", "carla", "--carla-fov", "60", "--attentive-walker", "3",
            "--distracted-walker", "walker.pedestrian.0008", "--out", str(tmp_path / "o")]  # fmt: skip
    code, _, err = _run(argv, capsys)
    assert code == 2 and "stop here" in err
    assert seen == {"town": "Town03", "fov_deg": 60.0, "attentive_walker": 3,
                    "distracted_walker": "walker.pedestrian.0008"}  # fmt: skip
