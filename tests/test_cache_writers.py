"""The compiled-code cache on a full disk or an unusable cache folder: every failure names
the file it was writing (the library in ``compiled/``, not a temporary file, and not
nothing), the command line says it in one line with exit code 2, and nothing is left
behind that a later run would load (no half library, no staging folder, no lock).

A full disk is simulated by a write that raises ``ENOSPC`` (monkeypatched ``os.fsync``,
a build that fails, ``/dev/full``), which works as root too, where ``chmod`` does not
stop a write."""
from __future__ import annotations

import errno
import os
import re
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from analysis.cli import main as biped_main
from biped_casadi import Design, caching, simd
from biped_casadi.numerics import cached_library, compiler_reason

LD_FULL = ("/usr/bin/ld: final link failed: No space left on device\n"
           "collect2: error: ld returned 1 exit status\n")


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _write_half_then_fail(tmp, out):
    with open(out, "wb") as fh:
        fh.write(b"\x7fELF half a library")
    _disk_full()


def _compiler_fails(tmp, out):
    raise subprocess.CalledProcessError(1, ["gcc", "-o", out], stderr=LD_FULL.encode())


@pytest.mark.parametrize("build, reason", [
    (lambda tmp, out: _disk_full(), "No space left on device"),
    (_write_half_then_fail, "No space left on device"),
    (_compiler_fails, "the C compiler failed (exit 1): /usr/bin/ld: final link failed: No "
                      "space left on device"),
])
def test_a_failed_build_names_the_library_and_leaves_nothing(build, reason, tmp_path,
                                                             monkeypatch):
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    with pytest.raises(OSError) as e:
        cached_library("lib_0123.so", build)
    assert (e.value.filename, e.value.strerror) == (str(tmp_path / "compiled" / "lib_0123.so"),
                                                    reason)
    assert list((tmp_path / "compiled").iterdir()) == []
    assert str(e.value) in (f"[Errno 28] {reason}: '{e.value.filename}'",
                            f"{e.value.filename}: {reason}")


def test_a_library_is_on_disk_before_it_is_in_place(tmp_path, monkeypatch):
    """The output is fsynced before it is moved into place: a full disk then (its data
    not written) fails the build, naming the library; a complete build is kept."""
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))

    def build(tmp, out):
        Path(out).write_bytes(b"library")

    monkeypatch.setattr(os, "fsync", _disk_full)
    with pytest.raises(OSError, match="No space left") as e:
        cached_library("lib_fsync.so", build)
    assert e.value.filename == str(tmp_path / "compiled" / "lib_fsync.so")
    assert list((tmp_path / "compiled").iterdir()) == []
    monkeypatch.undo()
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    so = cached_library("lib_fsync.so", build)
    assert so.read_bytes() == b"library" and sorted(p.name for p in so.parent.iterdir()) == \
        ["lib_fsync.so"]


def test_a_cache_folder_that_is_a_file_is_named(tmp_path, monkeypatch):
    afile = tmp_path / "cache"
    afile.write_text("not a folder")
    monkeypatch.setenv("BIPED_CACHE_DIR", str(afile))
    with pytest.raises(OSError) as e:
        cached_library("lib.so", lambda tmp, out: None)
    assert e.value.filename == str(afile / "compiled") and e.value.errno == errno.ENOTDIR


def test_a_cache_folder_that_is_a_broken_link_says_so(tmp_path, monkeypatch):
    """Not 'File exists' (what making a folder at a link to nowhere says)."""
    link = tmp_path / "cache"
    link.symlink_to(tmp_path / "nowhere" / "cache")
    monkeypatch.setenv("BIPED_CACHE_DIR", str(link))
    with pytest.raises(OSError) as e:
        cached_library("lib.so", lambda tmp, out: None)
    assert (e.value.filename, e.value.strerror) == (
        str(link), f"a broken link (to {tmp_path / 'nowhere' / 'cache'})")


def test_a_lock_that_cannot_be_written_is_not_left(tmp_path, monkeypatch):
    """A full disk when the lock's process id is written: the block runs unguarded (as
    in a folder that cannot be written) and no empty lock file stays behind."""
    target = tmp_path / "lib.so"
    monkeypatch.setattr(caching.os, "fdopen", _disk_full)
    ran = []
    with caching.file_lock(target, poll=0.01):
        ran.append(True)
    assert ran == [True] and list(tmp_path.iterdir()) == []


def test_compiler_reason_is_the_line_that_says_why():
    assert compiler_reason(LD_FULL) == "/usr/bin/ld: final link failed: No space left on device"
    assert compiler_reason(b"x.c:3:1: error: expected ';'\ncollect2: error: ld returned 1") \
        == "x.c:3:1: error: expected ';'"
    assert compiler_reason("collect2: error: ld returned 1 exit status") == \
        "collect2: error: ld returned 1 exit status"
    assert compiler_reason("") == "" and compiler_reason(None) == ""


# ------------------------------------------------------------------ the SIMD cache
def _kernel():
    x = ca.SX.sym("x", 2)
    return {"f": (ca.Function("writers_f", [x], [ca.sin(x[0]) * x[1]]), 0, ["sample"])}


@pytest.mark.skipif(not simd.available(), reason="no AVX2/FMA or no gcc")
def test_simd_cache_on_a_full_disk_and_a_damaged_index(tmp_path, monkeypatch):
    """On a full disk the kernels are not built (the caller keeps CasADi's map) and
    nothing is left in the cache folder; an index whose content is not a library's name
    (a file of zeros after a crash) is replaced, the library made again."""
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(simd, "_LOADED", {})
    from biped_casadi import numerics
    monkeypatch.setattr(numerics, "_NOT_COMPILED", set())
    with monkeypatch.context() as m:
        m.setattr(os, "fsync", _disk_full)
        with pytest.warns(numerics.NotCompiledWarning, match="No space left on device"):
            assert simd.kernels(_kernel(), "writers") is None
    assert list((tmp_path / "compiled").iterdir()) == []
    X = np.array([[0.1, 0.2, 0.3, 0.4, 0.5], [1.0, 2.0, 3.0, 4.0, 5.0]])
    want = simd.kernels(_kernel(), "writers")["f"](X)[0]
    (index,) = (tmp_path / "compiled").glob("writers_simd_*.idx")
    (so,) = (tmp_path / "compiled").glob("writers_simd_*.so")
    for damaged in (b"\0" * 34, b"", b"../../elsewhere.so"):
        index.write_bytes(damaged)
        monkeypatch.setattr(simd, "_LOADED", {})
        got = simd.kernels(_kernel(), "writers")["f"](X)[0]
        assert np.array_equal(got, want) and index.read_text() == so.name


# ------------------------------------------------------------------ the command line
@pytest.fixture
def gait_file(gait, tmp_path):
    return str(gait.save(tmp_path / "gait.json"))


MUJOCO = ["mujoco", "--controller", "vc", "--steps", "1", "--no-eig"]


def test_biped_mujoco_on_a_full_cache_disk_is_one_line(gait_file, tmp_path, monkeypatch,
                                                        capsys):
    pytest.importorskip("mujoco")
    cache = tmp_path / "cache"
    monkeypatch.setenv("BIPED_CACHE_DIR", str(cache))
    monkeypatch.setattr(os, "fsync", _disk_full)
    rc = biped_main(MUJOCO + ["--gait", gait_file])
    err = capsys.readouterr().err
    law = re.escape(str(cache / "compiled")) + r"/mujoco-law-[0-9a-f]{24}\.so"
    assert rc == 2 and re.fullmatch(rf"biped mujoco: error: {law}: No space left on device\n",
                                    err), err
    assert [p.name for p in (cache / "compiled").iterdir()
            if p.name.startswith(("mujoco-law", ".mujoco-law"))] == []


def test_biped_mujoco_with_a_failing_compiler_names_the_library(gait_file, tmp_path,
                                                                monkeypatch, capsys):
    pytest.importorskip("mujoco")
    from biped_casadi.control.compiled import CompilerError
    from biped_casadi.mujoco import law

    def fails(folder, out):
        raise CompilerError(f"gcc failed (exit 1): {compiler_reason(LD_FULL)}")

    cache = tmp_path / "cache"
    monkeypatch.setenv("BIPED_CACHE_DIR", str(cache))
    monkeypatch.setattr(law, "build_library", fails)
    monkeypatch.setattr(law, "find_c_compiler", lambda: ["gcc"])
    rc = biped_main(MUJOCO + ["--gait", gait_file])
    err = capsys.readouterr().err
    lib = re.escape(str(cache / "compiled")) + r"/mujoco-law-[0-9a-f]{24}\.so"
    assert rc == 2 and re.fullmatch(
        rf"biped mujoco: error: --law c: {lib}: gcc failed \(exit 1\): /usr/bin/ld: final "
        r"link failed: No space left on device \(or use --law python\)\n", err), err
    assert [p.name for p in (cache / "compiled").iterdir() if "mujoco-law" in p.name] == []


def test_biped_mujoco_with_a_cache_that_is_a_file(gait_file, tmp_path, monkeypatch, capsys):
    pytest.importorskip("mujoco")
    afile = tmp_path / "cache"
    afile.write_text("")
    monkeypatch.setenv("BIPED_CACHE_DIR", str(afile))
    assert biped_main(MUJOCO + ["--gait", gait_file]) == 2
    assert capsys.readouterr().err == (f"biped mujoco: error: {afile / 'compiled'}: Not a "
                                       "directory\n")


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_the_private_copy_of_a_library_on_a_full_disk(gait, tmp_path, monkeypatch):
    """The compiled law is loaded from a private copy in the temporary folder: a full
    one is named (not only the library, which is fine)."""
    pytest.importorskip("mujoco")
    import tempfile

    from biped_casadi.control.compiled import CompiledController
    from biped_casadi.mujoco.law import compiled_law
    design = Design.vc(gait)
    lib = compiled_law(design)
    copy = tmp_path / "biped_controller_x.so"

    def mkstemp(prefix="", suffix=""):
        copy.touch()
        return os.open("/dev/full", os.O_WRONLY), str(copy)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    with pytest.raises(ValueError) as e:
        CompiledController(lib, design.controller_for())
    assert str(e.value) == (f"library: cannot load {lib} ({copy} (its private copy): No "
                            "space left on device)")
    assert not copy.exists()


def test_compiled_code_not_built_is_one_note(gait_file, tmp_path, monkeypatch, capsys):
    """A full disk while the closed loop's library is built: the command still runs
    (CasADi evaluates the Functions) and says once why it is slower."""
    from biped_casadi import numerics
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(numerics, "_NOT_COMPILED", set())
    monkeypatch.setattr(os, "fsync", _disk_full)
    rc = biped_main(["simulate", "--gait", gait_file, "--controller", "vc", "--steps", "1",
                     "--jit"])
    err = capsys.readouterr().err
    notes = [ln for ln in err.splitlines() if "compiled code not built" in ln]
    assert rc == 0 and len(notes) == 1, err
    assert notes[0].startswith("biped simulate: note: compiled code not built (") \
        and "No space left on device" in notes[0], err
