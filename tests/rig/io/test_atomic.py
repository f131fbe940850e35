"""The one atomic file/folder writer (rig/io/atomic.py), with and without renameat2."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from rig.io import atomic
from rig.io.atomic import (
    TargetExistsError,
    move_into_place,
    rename_exchange,
    rename_noreplace,
    staged_file,
    staged_folder,
    write_bytes_atomic,
)


def _hidden(root: Path) -> list[str]:
    """Temporaries are hidden (``.name...``) beside their destination: none may be left."""
    return sorted(str(p.relative_to(root)) for p in root.rglob(".*"))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.fixture(params=["renameat2", "fallback"])
def rename(request, monkeypatch):
    """Run a test with the kernel's renameat2 and with the portable fallback (as if it were missing)."""
    if request.param == "fallback":

        def missing(src, dst):
            raise OSError(errno.ENOSYS, "renameat2 is not available")

        monkeypatch.setattr(atomic, "rename_noreplace", missing)
        monkeypatch.setattr(atomic, "rename_exchange", missing)
    return request.param


# ----------------------------------------------------------------------------------------------- files


def test_write_bytes_creates_and_replaces_with_umask_permissions(tmp_path, rename):
    path = tmp_path / "a.bin"
    write_bytes_atomic(path, b"one")
    assert path.read_bytes() == b"one"
    write_bytes_atomic(path, b"two")
    assert path.read_bytes() == b"two"
    assert path.stat().st_mode & 0o777 == 0o666 & ~_umask()
    assert _hidden(tmp_path) == [] and [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_write_bytes_parents(tmp_path):
    with pytest.raises(FileNotFoundError):
        write_bytes_atomic(tmp_path / "no" / "a.bin", b"x")
    write_bytes_atomic(tmp_path / "no" / "such" / "a.bin", b"x", make_parents=True)
    assert (tmp_path / "no" / "such" / "a.bin").read_bytes() == b"x"


def test_write_bytes_never_replaces_a_folder(tmp_path, rename):
    folder = tmp_path / "a.bin"
    folder.mkdir()
    (folder / "keep.txt").write_text("mine")
    with pytest.raises(IsADirectoryError):
        write_bytes_atomic(folder, b"x")
    assert [p.name for p in folder.iterdir()] == ["keep.txt"] and _hidden(tmp_path) == []


def test_a_failed_write_leaves_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space"):
        write_bytes_atomic(path, b"new")
    assert path.read_bytes() == b"old" and _hidden(tmp_path) == []


def test_staged_file_keeps_the_suffix_and_refuses_an_existing_target(tmp_path, rename):
    out = tmp_path / "head.obj"
    with staged_file(out) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".") and tmp.suffix == ".obj"
        tmp.write_text("first")
    assert out.read_text() == "first"
    with pytest.raises(TargetExistsError) as info, staged_file(out) as tmp:
        tmp.write_text("second")
    assert info.value.filename == str(out) and isinstance(info.value, FileExistsError)
    assert out.read_text() == "first" and _hidden(tmp_path) == []
    with staged_file(out, replace=True) as tmp:
        tmp.write_text("third")
    assert out.read_text() == "third" and _hidden(tmp_path) == []


def test_a_file_that_appears_while_writing_is_not_replaced(tmp_path, rename):
    out = tmp_path / "head.obj"
    with pytest.raises(TargetExistsError), staged_file(out) as tmp:
        tmp.write_text("mine")
        out.write_text("theirs")  # another process finished first
    assert out.read_text() == "theirs" and _hidden(tmp_path) == []


def test_an_error_or_interrupt_in_the_block_removes_the_temporary(tmp_path):
    out = tmp_path / "a.txt"
    for exc in (RuntimeError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(exc)), staged_file(out) as tmp:
            tmp.write_text("partial")
            raise exc
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------- folders


def test_staged_folder_creates_replaces_and_calls_before_move(tmp_path, rename):
    out = tmp_path / "out"
    seen = []
    with staged_folder(out, before_move=lambda tmp: seen.append(sorted(p.name for p in tmp.iterdir()))) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".")
        (tmp / "a.txt").write_text("1")
    assert seen == [["a.txt"]] and [p.name for p in out.iterdir()] == ["a.txt"]
    assert out.stat().st_mode & 0o777 == 0o777 & ~_umask()
    with staged_folder(out, replace=True) as tmp:
        (tmp / "b.txt").write_text("2")
    assert [p.name for p in out.iterdir()] == ["b.txt"] and _hidden(tmp_path) == []


def test_a_folder_that_appears_is_refused_even_when_empty(tmp_path, rename):
    out = tmp_path / "out"
    with pytest.raises(TargetExistsError), staged_folder(out) as tmp:
        (tmp / "mine.txt").write_text("x")
        out.mkdir()  # os.rename would silently replace an empty folder
    assert list(out.iterdir()) == [] and _hidden(tmp_path) == []


def test_check_replace_can_refuse_and_nothing_changes(tmp_path, rename):
    out = tmp_path / "out"
    out.mkdir()
    (out / "user.txt").write_text("not ours")

    def refuse(path: Path) -> None:
        raise PermissionError(f"{path} is not ours")

    with (
        pytest.raises(PermissionError, match="not ours"),
        staged_folder(out, replace=True, check_replace=refuse) as tmp,
    ):
        (tmp / "a.txt").write_text("1")
    assert [p.name for p in out.iterdir()] == ["user.txt"] and _hidden(tmp_path) == []


def test_a_folder_never_replaces_a_file(tmp_path, rename):
    out = tmp_path / "out"
    out.write_text("a file")
    with pytest.raises(NotADirectoryError), staged_folder(out, replace=True) as tmp:
        (tmp / "a.txt").write_text("1")
    assert out.read_text() == "a file" and _hidden(tmp_path) == []


# ------------------------------------------------------------------------------------------ the renames


def test_rename_noreplace_and_exchange(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("A")
    b.write_text("B")
    try:
        rename_exchange(a, b)
    except OSError as exc:
        if exc.errno in (errno.ENOSYS, errno.EINVAL):
            pytest.skip("no renameat2 here")
        raise
    assert (a.read_text(), b.read_text()) == ("B", "A")
    with pytest.raises(FileExistsError):
        rename_noreplace(a, b)
    rename_noreplace(a, tmp_path / "c")
    assert (tmp_path / "c").read_text() == "B" and not a.exists()
    with pytest.raises(FileNotFoundError):
        rename_exchange(a, b)


def test_move_into_place_rejects_an_unknown_kind(tmp_path):
    with pytest.raises(ValueError, match="kind"):
        move_into_place(tmp_path / "a", tmp_path / "b", kind="link")
