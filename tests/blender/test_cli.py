"""The command line of FORMATS.md §4, both ways in."""

import os
import subprocess
import sys

from repo_paths import REPO

from bodycal_addon.app import cli, cli_bridge

COMMANDS = ("calibrate-user", "calibrate-avatar", "retarget", "transfer", "batch", "record", "stream", "demo")


def _run(*args):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=300)


def test_help_lists_every_command():
    out = _run("--help")
    assert out.returncode == 0
    for command in COMMANDS:
        assert command in out.stdout


def test_bad_arguments_give_one_line_and_exit_2():
    out = _run("retarget", "only-a-recording.json")
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "--user" in lines[0]
    assert "Traceback" not in out.stderr


def test_unknown_command_exits_2(capsys):
    assert cli.main(["frobnicate"]) == 2
    err = capsys.readouterr().err
    assert "invalid choice" in err and "Traceback" not in err


def test_blender_cli_command_handler_runs_the_same_entry_point(capsys):
    # bpy.utils.register_cli_command cannot be invoked from the module (no `-c`): call the handler.
    assert cli_bridge.run(["--help"]) == 0
    assert "calibrate-avatar" in capsys.readouterr().out


def test_a_bad_filter_is_one_line_before_anything_is_read(tmp_path):
    out = _run("retarget", "missing.bcrec.json", "--user", "u.body.json", "--avatar", "a.blend", "--filter", "1,2,3",
               "-o", str(tmp_path / "o.blend"))
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert "--filter" in line and "expected 2 or 4 numbers" in line and "Traceback" not in out.stderr


def test_retarget_and_transfer_take_the_same_bake_options():
    """Root motion and the Rigify target apply to whatever is baked onto the avatar: a transfer onto
    a game rig or a generated Rigify rig needs them as much as a retarget does."""
    parser = cli.build_parser()
    common = ["--root-motion", "in-place", "--rigify-target", "def", "--tolerance", "0.2", "--fps", "30",
              "--placement", "performer", "--no-plant-feet", "-o", "a.blend", "-o", "a.fbx"]
    retarget = parser.parse_args(["retarget", "r.bcrec.json", "--user", "u.json", "--avatar", "a.blend", *common])
    transfer = parser.parse_args(["transfer", "s.bvh", "--avatar", "a.blend", *common])
    for args in (retarget, transfer):
        assert (args.root_motion, args.rigify_target, args.tolerance, args.fps, args.placement, args.plant_feet,
                args.output) == ("in-place", "def", 0.2, 30.0, "performer", False, ["a.blend", "a.fbx"])


def test_a_command_leaves_no_blender_temp_folder(tmp_path):
    """Blender as a module makes a session folder (`<temp>/blender_XXXXXX`) that its exit handlers
    remove; the command line leaves without them (they can hang Blender 4.5), so it removes the
    folder itself: a batch farm otherwise collected one per job."""
    temp = tmp_path / "temp"
    temp.mkdir()
    env = {**os.environ, "TMPDIR": str(temp)}
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "calibrate-avatar", str(tmp_path / "missing.blend"),
                          "-o", str(tmp_path / "a.body.json")], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 2 and len(out.stderr.splitlines()) == 1, out.stderr
    assert [p.name for p in temp.iterdir()] == []


def test_version_is_the_manifests():
    import tomllib

    out = _run("--version")
    manifest = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    assert out.returncode == 0 and out.stdout.strip() == f"bodycal {manifest['version']}", out.stderr


def test_an_argument_error_names_the_program_once():
    """argparse's message already carries its program: the line is `bodycal: error: ...` or
    `bodycal <command>: error: ...`, never both."""
    top = _run("calibrate-user", "a.bcrec.json", "-o", "u.body.json", "stray")
    (line,) = top.stderr.strip().splitlines()
    assert top.returncode == 2 and line == "bodycal: error: unrecognized arguments: stray"
    sub = _run("retarget", "a.bcrec.json")
    (line,) = sub.stderr.strip().splitlines()
    assert sub.returncode == 2 and line.startswith("bodycal retarget: error: the following arguments are required")


def test_every_argument_of_every_command_has_help():
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    missing = [f"{name} {a.dest}" for name, p in sub.choices.items() for a in p._actions
               if a.help in (None, "") and a.dest != "help"]
    assert missing == []
    assert all(sub.choices[c].description or any(ch.dest == c for ch in sub._choices_actions) for c in COMMANDS)
