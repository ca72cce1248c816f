"""An output never destroys what the user has (FORMATS.md §4, "Outputs"). Every bad output path ends
in exit 2 with one line on stderr, before any work, with every input byte-identical and no temporary
file left."""

import hashlib
import os
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import bpy
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from repo_paths import REPO

from bodycal_addon.app import cli
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core import outputs, paths
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.io import save_recording
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A recording (JSON, and CSV + sidecar), a user file and an avatar .blend, in one folder."""
    folder = tmp_path_factory.mktemp("inputs")
    perf = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], seed=5)
    rec.name = "clap"
    rec_path, _truth = synthetic.write_session(folder, "clap", rec, truth)
    csv_path, sidecar = save_recording(rec, folder / "take.csv")
    user = truth.body_model().save(folder / "performer.body.json")
    bpy.ops.wm.read_homefile(use_empty=True)
    rigs.build_procedural_avatar()
    blend = folder / "avatar.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_homefile(use_empty=True)
    return {"folder": folder, "rec": Path(folder / rec_path.name), "csv": csv_path, "sidecar": sidecar,
            "user": user, "blend": blend}


def _run(*args):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=300)


def _hashes(folder: Path) -> dict[str, str]:
    """Every file under `folder` (links not followed) by its content's hash: nothing changed,
    nothing added (a stray temp), nothing removed."""
    return {str(p.relative_to(folder)): (f"link->{os.readlink(p)}" if p.is_symlink() else
                                          hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(folder.rglob("*"))}


def _refused(out, *words):
    """Exit 2, exactly one line on stderr naming the problem, no traceback."""
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    assert "Traceback" not in out.stderr
    (line,) = out.stderr.strip().splitlines()
    for word in words:
        assert word in line, line
    return line


def _retarget(i, output, *extra, recording=None):
    return ("retarget", recording or i["rec"], "--user", i["user"], "--avatar", i["blend"], "-o", output, *extra)


def _cases(i):
    """(command line, what the message must say) for an output that is one of the inputs."""
    return {
        "calibrate-user -o REC": (("calibrate-user", i["rec"], "-o", i["rec"]), "is the recording"),
        "calibrate-user take.csv -o take.json": (("calibrate-user", i["csv"], "-o", i["sidecar"]), "sidecar"),
        "calibrate-user -o REC spelled with ..": (("calibrate-user", i["rec"], "-o",
                                                   i["folder"] / "no_such_folder" / ".." / i["rec"].name),
                                                  "is the recording"),
        "calibrate-avatar A.blend -o A.blend": (("calibrate-avatar", i["blend"], "-o", i["blend"]), "avatar .blend"),
        "retarget -o avatar": (_retarget(i, i["blend"]), "avatar .blend"),
        "retarget -o user": (_retarget(i, i["user"]), "user file"),
        "retarget -o recording": (_retarget(i, i["rec"]), "is the recording"),
        "retarget -o sidecar": (_retarget(i, i["sidecar"], recording=i["csv"]), "sidecar"),
        # --overwrite never allows it
        "retarget -o user --overwrite": (_retarget(i, i["user"], "--overwrite"), "user file"),
    }


CASE_NAMES = ["calibrate-user -o REC", "calibrate-user take.csv -o take.json", "calibrate-user -o REC spelled with ..",
              "calibrate-avatar A.blend -o A.blend", "retarget -o avatar", "retarget -o user", "retarget -o recording",
              "retarget -o sidecar", "retarget -o user --overwrite"]


@pytest.mark.parametrize("case", CASE_NAMES)
def test_an_output_that_is_an_input_is_refused_and_the_input_kept(inputs, case):
    argv, says = _cases(inputs)[case]
    before = _hashes(inputs["folder"])
    _refused(_run(*argv), "-o", says, "choose another output path")
    assert _hashes(inputs["folder"]) == before


def test_a_hard_link_to_the_recording_is_the_recording(inputs, tmp_path):
    """Another name for the same file (os.path.samefile), not only the same resolved path."""
    link = tmp_path / "other_name.json"
    os.link(inputs["rec"], link)
    before = _hashes(inputs["folder"])
    _refused(_run("calibrate-user", inputs["rec"], "-o", link, "--overwrite"), "is the recording")
    assert _hashes(inputs["folder"]) == before


def test_a_symlink_output_is_refused_and_neither_link_nor_target_changes(inputs, tmp_path):
    target = tmp_path / "mine.body.json"
    target.write_text("the user's own file")
    link = tmp_path / "link.body.json"
    link.symlink_to(target)
    before = _hashes(tmp_path)
    _refused(_run("calibrate-user", inputs["rec"], "-o", link, "--overwrite"), str(link), "symbolic link")
    assert _hashes(tmp_path) == before and link.is_symlink()


def test_a_pipe_output_is_refused_and_stays_a_pipe(inputs, tmp_path):
    """A named pipe stands for every non-regular file on the command line: a device such as
    /dev/full is not used there, since a regression run as root would replace the machine's own."""
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    before = _hashes(inputs["folder"])
    _refused(_run("calibrate-user", inputs["rec"], "-o", pipe, "--overwrite"), str(pipe), "not a regular file")
    _refused(_run(*_retarget(inputs, pipe, "--overwrite")), str(pipe), "not a regular file")
    assert stat.S_ISFIFO(os.lstat(pipe).st_mode)  # not replaced by a file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]
    assert _hashes(inputs["folder"]) == before


@pytest.mark.parametrize("device", ["/dev/null", "/dev/full"])
def test_a_device_is_refused_before_anything_is_written(device):
    with pytest.raises(BodyCalError, match="not a regular file") as err:
        outputs.check_output(device, overwrite=True)
    assert err.value.line().startswith(f"{device}: -o:")


@pytest.mark.parametrize("command", ["calibrate-user", "retarget"])
def test_an_existing_folder_as_output_is_refused_without_a_stray_temp(inputs, tmp_path, command):
    folder = tmp_path / "o"
    folder.mkdir()
    argv = ("calibrate-user", inputs["rec"], "-o", folder) if command == "calibrate-user" else _retarget(inputs, folder)
    _refused(_run(*argv, "--overwrite"), str(folder), "is a folder")
    assert list(tmp_path.rglob("*")) == [folder]  # nothing written beside or inside it


def _unwritable_folder(tmp_path) -> Path:
    """A folder no one may create files in: a read-only folder, or for root (whom permissions do
    not stop) a path under /proc."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o500)
    if os.access(folder, os.W_OK):
        return Path("/proc/bodycal-no-such-folder")
    return folder


@pytest.mark.parametrize("command", ["calibrate-user", "calibrate-avatar", "retarget"])
def test_an_unwritable_folder_is_one_line_before_any_work(inputs, tmp_path, command):
    folder = _unwritable_folder(tmp_path)
    target = folder / "out.file"
    argv = {"calibrate-user": ("calibrate-user", inputs["rec"], "-o", target),
            "calibrate-avatar": ("calibrate-avatar", inputs["blend"], "-o", target),
            "retarget": _retarget(inputs, target)}[command]
    try:
        out = _run(*argv)
    finally:
        if folder.is_relative_to(tmp_path):
            folder.chmod(0o700)
    line = _refused(out, str(target), "cannot write in", "choose a folder you can write to")
    assert "calibrated" not in out.stdout and "Baked" not in out.stdout, line  # refused before the work
    if folder.is_relative_to(tmp_path):
        assert list(folder.iterdir()) == []


def test_an_existing_user_file_is_replaced_only_with_overwrite(inputs, tmp_path):
    out_path = tmp_path / "user.body.json"
    out_path.write_text("the user's earlier calibration")
    _refused(_run("calibrate-user", inputs["rec"], "-o", out_path), str(out_path), "already exists", "--overwrite")
    assert out_path.read_text() == "the user's earlier calibration"

    before = _hashes(inputs["folder"])
    done = _run("calibrate-user", inputs["rec"], "-o", out_path, "--overwrite", "--allow-defaults")  # T-pose only
    assert done.returncode == 0, done.stderr[-2000:]
    assert BodyModel.load(out_path).kind == "user"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["user.body.json"]  # no temp left beside it
    assert _hashes(inputs["folder"]) == before


def test_an_existing_blend_is_replaced_only_with_overwrite(inputs, tmp_path):
    out_path = tmp_path / "out.blend"
    out_path.write_bytes(b"the user's earlier bake")
    _refused(_run(*_retarget(inputs, out_path)), str(out_path), "already exists", "--overwrite")
    assert out_path.read_bytes() == b"the user's earlier bake"

    before = _hashes(inputs["folder"])
    done = _run(*_retarget(inputs, out_path, "--overwrite"))
    assert done.returncode == 0, done.stderr[-2000:]
    head = out_path.read_bytes()[:7]
    assert head == b"BLENDER" or head[:4] == b"\x28\xb5\x2f\xfd"  # plain, or zstd (Blender 5.0's default)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.blend"]  # no temp, no .blend1 backup
    assert _hashes(inputs["folder"]) == before


def test_a_new_output_path_works_as_before_folders_included(inputs, tmp_path):
    out_path = tmp_path / "new" / "folder" / "avatar.body.json"
    done = _run("calibrate-avatar", inputs["blend"], "-o", out_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert BodyModel.load(out_path).kind == "avatar"
    assert sorted(p.name for p in out_path.parent.iterdir()) == ["avatar.body.json"]


def test_an_os_error_no_check_foresaw_is_one_line(monkeypatch, capsys, tmp_path):
    """A file that vanishes or a disk that fills mid-way: cli.py turns any OSError into one line."""
    import bodycal_addon.recording.io as recording_io

    def vanished(path, **_options):  # load_recording(path, hands=...)
        raise FileNotFoundError(2, "No such file or directory", str(path))

    monkeypatch.setattr(recording_io, "load_recording", vanished)
    assert cli.main(["calibrate-user", "gone.bcrec.json", "-o", str(tmp_path / "u.body.json")]) == 2
    err = capsys.readouterr().err
    (line,) = err.strip().splitlines()
    assert "gone.bcrec.json" in line and "No such file" in line and "Traceback" not in err


# The engine module itself.

def test_a_failing_writer_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="writer broke"):
        with outputs.replacing(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer broke")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_replacing_keeps_the_replaced_files_permissions(tmp_path):
    target = tmp_path / "shared.body.json"
    target.write_text("old")
    target.chmod(0o640)
    outputs.write_text(target, "new")
    assert target.read_text() == "new" and (target.stat().st_mode & 0o777) == 0o640


def test_a_model_that_cannot_be_written_leaves_the_target_untouched(tmp_path):
    target = tmp_path / "m.body.json"
    target.write_text("old")
    model = BodyModel(kind="user", name="nan")
    model.reference_time = float("nan")
    with pytest.raises(ValueError):
        model.save(target)
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.body.json"]


@settings(max_examples=40, deadline=None)
@given(text=st.text(max_size=200), name=st.text(alphabet="abcdefghijklmnopqrstuvwxyz_.-", min_size=1, max_size=20),
       existed=st.booleans(), overwrite=st.booleans())
def test_write_text_is_all_or_nothing(text, name, existed, overwrite):
    """Whatever the name and content: the target ends with the new text exactly when it may be
    replaced, else keeps the old one; no other file ever appears beside it."""
    if name in (".", ".."):
        return
    with tempfile.TemporaryDirectory() as d:
        target = Path(d) / name
        if existed:
            target.write_text("old")
        try:
            outputs.write_text(target, text, overwrite=overwrite)
            wrote = True
        except BodyCalError as exc:
            wrote = False
            assert "already exists" in exc.line()
        assert wrote == (overwrite or not existed)
        assert target.read_bytes() == (text.encode("utf-8") if wrote else b"old")
        assert [p.name for p in Path(d).iterdir()] == [name]


@settings(max_examples=30, deadline=None)
@given(spelling=st.lists(st.sampled_from(["sub", "..", "."]), max_size=5))
def test_any_spelling_of_an_input_is_that_input(spelling):
    """`sub/../take.json`, `./take.csv`...: a roundabout path to the recording or its sidecar
    (existing or not) is refused; one that ends elsewhere is not."""
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "sub").mkdir()
        rec = Path(d) / "take.csv"
        rec.write_text("t")
        depth = 0
        for part in spelling:
            depth += 1 if part == "sub" else -1 if part == ".." else 0
            if depth < 0:  # above the temporary folder: not ours to probe
                return
        for _what, name in ((w, p.name) for w, p in outputs.recording_inputs(rec)):
            out = Path(d).joinpath(*spelling, name)
            if depth == 0:
                with pytest.raises(BodyCalError, match="an input of this command"):
                    outputs.check_output(out, inputs=outputs.recording_inputs(rec), overwrite=True)
            else:  # sub/take.json is another file
                assert outputs.check_output(out, inputs=outputs.recording_inputs(rec), overwrite=True) == out
