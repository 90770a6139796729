"""Report folders: the lock, the manifest and the write-then-move that keep a user's files safe.

A report folder is written like this (:class:`ReportFolder`):

1. lock it (``fcntl.flock`` on ``.lieseries-lock`` inside it; the kernel drops the lock when its holder dies, so
   a killed run leaves no stale lock), before any computation: a second run into the same folder is refused;
2. check it: the manifest names only plain files inside the folder, and a file counts as lieseries' own only
   when its content still has the SHA-256 the manifest recorded (a user's file, a changed file or a symbolic link
   is never replaced or removed);
3. render the whole report into a staging folder inside it (same file system: every move is a rename);
4. commit, with Ctrl-C held back until it is done: rename each new file into place, remove the earlier report's
   files that were not written again, write the manifest. The manifest lists the old and the new hashes while
   files move, so it is true at every step.

An interrupted or failed run removes its staging folder and leaves the earlier report exactly as it was.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import os
import shutil
import stat
import tempfile
from pathlib import Path

from .interrupts import held

__all__ = ["ReportFolder", "FolderError", "MANIFEST", "LOCK", "STAGING_PREFIX"]

#: Lists the files lieseries wrote into a report folder with their SHA-256 (the only files it replaces or removes).
MANIFEST = ".lieseries-manifest.json"
#: The lock file of a report folder being written.
LOCK = ".lieseries-lock"
#: Prefix of the staging folder a report is rendered into before it is moved into place.
STAGING_PREFIX = ".lieseries-new-"
_MANIFEST_FORMAT = 2
_HEX = set("0123456789abcdef")


class FolderError(ValueError):
    """A report folder lieseries will not write into: it holds files lieseries did not write (without
    ``overwrite``), a file of the new report's name that is not lieseries' own, a manifest naming anything but a
    plain file inside the folder, or another run is writing it."""


def _sha256(path):
    """SHA-256 (hex) of the regular file ``path``, never read through a symbolic link; None for anything else."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            return None
        h = hashlib.sha256()
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _kind(path) -> str:
    """"missing", "file", "dir" or "other" (a symbolic link, a device...), without following a link."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return "missing"
    except NotADirectoryError:
        return "other"
    return "file" if stat.S_ISREG(mode) else "dir" if stat.S_ISDIR(mode) else "other"


def _real_dirs(out: Path, rel: str) -> bool:
    """True when every folder on the way from ``out`` to ``out/rel`` is a real folder (no symbolic link)."""
    p = out
    for part in rel.split("/")[:-1]:
        p = p / part
        if _kind(p) != "dir":
            return False
    return True


def _blocked(out: Path, rel: str) -> bool:
    """True when something on the way from ``out`` to ``out/rel`` exists and is not a real folder (a file, a
    symbolic link): a file cannot be moved there without going through it or replacing it."""
    p = out
    for part in rel.split("/")[:-1]:
        p = p / part
        kind = _kind(p)
        if kind == "missing":
            return False
        if kind != "dir":
            return True
    return False


def _plain_name(rel) -> bool:
    """A manifest entry: a relative path of plain names inside the folder, none of them lieseries' own files."""
    if not isinstance(rel, str) or not rel or "\\" in rel or "\x00" in rel or rel.startswith("/"):
        return False
    parts = rel.split("/")
    if any(p in ("", ".", "..") for p in parts):
        return False
    return parts[0] not in (MANIFEST, LOCK) and not parts[0].startswith(STAGING_PREFIX)


def _read_manifest(out: Path) -> dict:
    """``{relative path: set of SHA-256}`` from the folder's manifest ({} when there is none; an empty set for an
    entry of an older manifest, which recorded no hash). Raises FolderError for anything but a plain JSON file
    naming plain files inside the folder."""
    path = out / MANIFEST
    kind = _kind(path)
    if kind == "missing":
        return {}
    fix = f"delete `{path}` if the folder is yours, or choose another --out"
    if kind != "file":
        raise FolderError(f"`{path}` is not a regular file (a symbolic link?); lieseries touches nothing in "
                          f"`{out}`: {fix}")
    try:
        with open(os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0)), encoding="utf-8") as f:
            data = json.load(f)
    except (OSError, ValueError) as err:
        raise FolderError(f"`{path}` is not a manifest lieseries can read ({type(err).__name__}); lieseries "
                          f"touches nothing in `{out}`: {fix}") from None
    files = data.get("files") if isinstance(data, dict) else None
    if isinstance(files, list):  # an older manifest: names only, no hash proves a file is lieseries' own
        entries = {rel: set() for rel in files}
        listed = files
    elif isinstance(files, dict):
        entries, listed = {}, list(files)
        for rel, hashes in files.items():
            hashes = hashes if isinstance(hashes, list) else [hashes]
            if not all(isinstance(h, str) and len(h) == 64 and set(h) <= _HEX for h in hashes):
                raise FolderError(f"`{path}` gives `{rel}` a hash that is not a SHA-256; lieseries touches "
                                  f"nothing in `{out}`: {fix}")
            entries[rel] = set(hashes)
    else:
        raise FolderError(f"`{path}` has no list of files; lieseries touches nothing in `{out}`: {fix}")
    for rel in listed:
        if not _plain_name(rel):
            raise FolderError(f"`{path}` names `{rel}`, which is not a plain file inside `{out}`; lieseries "
                              f"touches nothing there: {fix}")
    return entries


def _ours(out: Path, entries: dict) -> dict:
    """``{relative path: SHA-256}`` of the files the manifest proves lieseries wrote: regular files, reached
    through real folders, whose content has a hash the manifest recorded."""
    ours = {}
    for rel, hashes in entries.items():
        if hashes and _real_dirs(out, rel):
            h = _sha256(out / rel)
            if h in hashes:
                ours[rel] = h
    return ours


def _entries(root: Path, skip=()):
    """Relative paths of everything in ``root`` but folders (files, symbolic links...), never following a link;
    top-level names in ``skip`` are left out. A generator: the files at the top come first."""
    for dirpath, dirnames, filenames in os.walk(root):
        base = Path(dirpath).relative_to(root).as_posix()
        prefix = "" if base == "." else base + "/"
        for d in list(dirnames):
            if os.path.islink(os.path.join(dirpath, d)):  # a link to a folder is an entry, not a folder to enter
                dirnames.remove(d)
                filenames.append(d)
            elif not prefix and d in skip:
                dirnames.remove(d)
        yield from sorted(prefix + f for f in filenames if prefix or f not in skip)


def _shown(names, n=3) -> str:
    return ", ".join(f"`{x}`" for x in names[:n]) + (", ..." if len(names) > n else "")


class ReportFolder:
    """A report folder held by this process (a context manager): locked, checked, written through a staging
    folder and committed whole.

    ``with ReportFolder(out_dir, overwrite) as folder:`` locks ``out_dir`` (created if missing) and checks it
    (:class:`FolderError` when another run holds it, when it holds files lieseries did not write and not
    ``overwrite``, or when a file named in ``names`` is there and is not lieseries' own). Inside,
    :meth:`staging` gives a fresh folder to write the report into and :meth:`commit` moves it into place. Leaving
    the block without a commit (an error, Ctrl-C) removes the staging folder and leaves ``out_dir`` as it was.

    Files lieseries did not write are never replaced or removed, with or without ``overwrite``: a file counts as
    lieseries' own only when the manifest lists it with the SHA-256 of its content.
    """

    def __init__(self, out_dir, overwrite: bool = False, names=("report.md", "data.json")):
        self.path = Path(out_dir)
        self.overwrite = bool(overwrite)
        self.names = tuple(names)
        self._fd = None
        self._created = False
        self._staging = None

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()
        return False

    # -- lock ----------------------------------------------------------------------------------------------
    def acquire(self) -> None:
        """Create the folder if missing, lock it and check it (before any computation)."""
        import fcntl

        out = self.path
        kind = _kind(out)
        if kind == "missing":
            out.mkdir(parents=True, exist_ok=True)
            self._created = True
        elif not out.is_dir():
            raise FolderError(f"`{out}` exists and is not a folder; choose another --out")
        lock = out / LOCK
        while True:
            try:
                fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
            except OSError as err:
                self._drop_created()
                raise FolderError(f"`{lock}` cannot be opened as a lock file ({err.strerror}); remove it if it is "
                                  "yours, or choose another --out") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = os.read(fd, 64).decode("ascii", "replace").strip() or "?"
                os.close(fd)
                raise FolderError(f"`{out}` is being written by another lieseries run (pid {holder}); wait for "
                                  "it to finish, or choose another --out") from None
            try:
                same = os.fstat(fd).st_ino == os.lstat(lock).st_ino
            except FileNotFoundError:  # the holder removed it as we opened it: take the new one
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        try:
            self._check(self.names, refuse_foreign=not self.overwrite)
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """Remove the staging folder (if not committed), unlock, and remove the folder if this run created it
        and left it empty; Ctrl-C waits until it is done (a staging folder half removed would be left behind)."""
        with held():
            if self._staging is not None:
                shutil.rmtree(self._staging, ignore_errors=True)
                self._staging = None
            if self._fd is not None:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.path / LOCK)
                os.close(self._fd)
                self._fd = None
            self._drop_created()

    def _drop_created(self) -> None:
        if self._created:
            with contextlib.suppress(OSError):
                self.path.rmdir()  # only when empty
            self._created = False

    # -- check ---------------------------------------------------------------------------------------------
    def _check(self, names, refuse_foreign: bool):
        """(manifest entries, files proven ours); FolderError for foreign files (when ``refuse_foreign``) and
        for any of ``names`` that is there and not ours."""
        out = self.path
        entries = _read_manifest(out)
        ours = _ours(out, entries)
        foreign = []
        if refuse_foreign:  # a few are enough to refuse and to name (a big folder is not walked to its end)
            skip = {MANIFEST, LOCK} | ({self._staging.name} if self._staging is not None else set())
            foreign = list(itertools.islice((rel for rel in _entries(out, skip) if rel not in ours), 4))
        older = any(not h for h in entries.values())
        why = (" (its manifest was written by an older lieseries and records no content hashes, so no file in it "
               "is known to be a report file: delete those files or the folder)" if older else "")
        if foreign and refuse_foreign:
            raise FolderError(f"`{out}` already holds files lieseries did not write ({_shown(foreign)}){why}; "
                              "choose another --out, or pass --overwrite to write there (only files lieseries "
                              "wrote itself are replaced)")
        clash = sorted({rel for rel in names
                        if rel not in ours and (_blocked(out, rel) or _kind(out / rel) != "missing")})
        if clash:
            links = [rel for rel in clash if _blocked(out, rel) or os.path.islink(out / rel)]
            what = (" (a symbolic link, or a file where a folder would go: lieseries never writes through one)"
                    if links else "")
            raise FolderError(f"`{out}` holds {_shown(clash)}{what}, which lieseries did not write (or which "
                              f"changed since){why}; the new report would replace it: move it away, or choose "
                              "another --out")
        return entries, ours

    # -- write ---------------------------------------------------------------------------------------------
    def staging(self) -> Path:
        """A fresh, empty folder inside the report folder to write the report into (moved by :meth:`commit`)."""
        if self._fd is None:
            raise RuntimeError("ReportFolder.staging() outside `with ReportFolder(...)`")
        if self._staging is None:
            self._staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=self.path))
        return self._staging

    def commit(self) -> None:
        """Move everything written into :meth:`staging` into place, remove the earlier report's files that were
        not written again and write the manifest; Ctrl-C waits until it is done."""
        stage = self.staging()
        out = self.path
        with held():
            new = {rel: _sha256(stage / rel) for rel in sorted(_entries(stage))}
            if any(h is None for h in new.values()):  # pragma: no cover - lieseries writes regular files only
                raise FolderError(f"the staging folder `{stage}` holds something that is not a regular file")
            try:
                _, ours = self._check(sorted(new), refuse_foreign=False)
            except FolderError as err:  # a file appeared (or changed) while the report was computed
                self._staging = None  # the computation is not thrown away
                raise FolderError(f"{err}; the new report is kept in `{stage}`") from None
            # the manifest first accepts both the old and the new content of each file, so it stays true
            # whatever moment the commit is stopped at
            both = {rel: sorted({h for h in (ours.get(rel), new.get(rel)) if h}) for rel in set(ours) | set(new)}
            self._write_manifest(stage, both)
            for rel in sorted(new):
                target = out / rel
                for parent in reversed(target.relative_to(out).parents[:-1]):
                    if _kind(out / parent) == "missing":
                        (out / parent).mkdir()
                os.replace(stage / rel, target)
            for rel in sorted(set(ours) - set(new), reverse=True):
                target = out / rel
                if _real_dirs(out, rel) and _sha256(target) == ours[rel]:
                    target.unlink()
                    for parent in target.relative_to(out).parents[:-1]:
                        with contextlib.suppress(OSError):
                            (out / parent).rmdir()  # a folder of the earlier report, once empty
            self._write_manifest(stage, {rel: new[rel] for rel in sorted(new)})
            shutil.rmtree(stage, ignore_errors=True)
            self._staging = None

    def _write_manifest(self, stage: Path, files: dict) -> None:
        tmp = stage / (MANIFEST + ".tmp")
        tmp.write_text(json.dumps({"format": _MANIFEST_FORMAT, "files": files}, indent=1, sort_keys=True),
                       encoding="utf-8")
        os.replace(tmp, self.path / MANIFEST)
