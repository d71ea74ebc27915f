"""A VTU set owns its directory (docs/viewing.md, "What a set owns"; issue 45, item 7).

- Only what a previous set of amfe's lists is deleted: the files its ``cases.json``
  and ``cases.pvd`` name (plain names of the form ``case_<name>.vtu``/``.vtp`` in the
  directory itself), never other files, however they are named (:func:`listed_files`).
- A symbolic link at a name the set writes is removed and a new file written in its
  place: its target, which may lie anywhere, is never written (:func:`unlink_links`).
- One writer per directory: ``DIR/.amfe-vtu.lock``, created with O_CREAT | O_EXCL as
  ``amfe dataset`` locks its file (amfe/dataset/lock.py); a second run into the same
  DIR is refused with a line naming the holder, a lock left by a killed run is reported
  with the command that removes it, never removed silently (:class:`SetLock`).
- ``--bc all`` removes a set of amfe's it does not write (an older top-level set, another
  bed's ``periodic/``) so that ``amfe view`` cannot render it (:func:`remove_set`).
- An output file (``-o``) that falls inside the set is refused (:func:`check_outside_set`).
"""
import json
import os
import re
import shlex

from amfe.errors import AmfeError
from amfe.io.atomic import host_name, pid_running
from amfe.io.pvd import PVD_NAME, SIDECAR_NAME, read_collection

LOCK_NAME = ".amfe-vtu.lock"
_CASE = re.compile(r"^case_[A-Za-z0-9_\-]+\.vt[up]$")
#: The subsets of ``--bc all`` (amfe.api.homogenize): DIR/<bc>/.
SUBSETS = ("kubc", "subc", "periodic")


def listed_files(directory):
    """Names (set) of the case files a previous set of amfe's in ``directory`` lists.

    From its ``cases.json`` (when it is amfe's sidecar) and its ``cases.pvd`` (when it
    parses); only plain case-file names in ``directory`` itself count. Empty when there
    is no set.
    """
    directory = os.fspath(directory)
    names = set()
    try:
        with open(os.path.join(directory, SIDECAR_NAME), encoding="utf-8") as fh:
            data = json.load(fh)
        if isinstance(data, dict) and isinstance(data.get("cases"), list) \
                and "amfe_version" in data:
            names |= {c.get("file") for c in data["cases"] if isinstance(c, dict)}
    except (OSError, ValueError):
        pass
    pvd = os.path.join(directory, PVD_NAME)
    if os.path.isfile(pvd):
        try:
            here = os.path.abspath(directory)
            names |= {os.path.basename(p) for _, p in read_collection(pvd)
                      if os.path.dirname(p) == here}
        except AmfeError:
            pass
    return {n for n in names if isinstance(n, str) and _CASE.match(n)}


def is_set(directory):
    """True when ``directory`` holds a set of amfe's (its cases.json or cases.pvd lists files)."""
    return bool(listed_files(directory))


def unlink_links(paths):
    """Remove each of ``paths`` that is a symbolic link (the link, never its target)."""
    for p in paths:
        if os.path.islink(p):
            os.remove(p)


def remove_set(directory):
    """Remove the set of amfe's in ``directory``: the files it lists, its cases.pvd and
    cases.json, its lock if stale; then the directory if it is left empty. Files it does
    not list are kept. Returns the names removed."""
    directory = os.fspath(directory)
    names = listed_files(directory)
    if not names:
        return []
    gone = []
    for n in sorted(names) + [PVD_NAME, SIDECAR_NAME]:
        p = os.path.join(directory, n)
        if os.path.lexists(p):
            os.remove(p)
            gone.append(n)
    try:
        os.rmdir(directory)
    except OSError:
        pass
    return gone


def check_outside_set(output, vtu_dir, bc=None, option="-o"):
    """Refuse an output file inside the set of ``vtu_dir`` (and its subsets under --bc all).

    A file of the set (cases.json, cases.pvd, case_*.vtu/.vtp, its lock) would be
    overwritten after cases.pvd claims the set complete.
    """
    if output is None or vtu_dir is None:
        return
    out = os.path.realpath(os.fspath(output))
    top = os.path.realpath(os.fspath(vtu_dir))
    dirs = [top] + ([os.path.join(top, s) for s in SUBSETS] if bc == "all" else [])
    name = os.path.basename(out)
    if os.path.dirname(out) in dirs and (name in (PVD_NAME, SIDECAR_NAME, LOCK_NAME)
                                         or _CASE.match(name)):
        raise AmfeError(f"{option} {output} falls inside the ParaView set of --vtu {vtu_dir} "
                        f"(it would overwrite the set's {name}); write the result elsewhere")
    if bc == "all" and out in dirs[1:]:
        raise AmfeError(f"{option} {output} is a directory of the --bc all set of --vtu "
                        f"{vtu_dir}; write the result elsewhere")


class SetLock:
    """``DIR/.amfe-vtu.lock``: one writer of a VTU set at a time (module docstring)."""

    def __init__(self, directory):
        self.directory = os.fspath(directory)
        self.path = os.path.join(self.directory, LOCK_NAME)
        self.token = None

    def __enter__(self):
        token = {"pid": os.getpid(), "host": host_name()}
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            raise AmfeError(self._held_message()) from None
        except OSError as exc:
            raise AmfeError(f"cannot create the lock file {self.path}: "
                            f"{exc.strerror or exc}") from None
        with os.fdopen(fd, "w") as fh:
            fh.write(json.dumps(token) + "\n")
        self.token = token
        return self

    def __exit__(self, *exc):
        if self.token is None:
            return
        try:
            with open(self.path) as fh:
                mine = json.load(fh) == self.token
        except (OSError, ValueError):
            mine = False
        if mine:
            os.remove(self.path)
        self.token = None

    def _held_message(self):
        rm = f"rm {shlex.quote(self.path)}"
        try:
            with open(self.path) as fh:
                holder = json.load(fh)
            pid, host = int(holder["pid"]), str(holder["host"])
        except (OSError, ValueError, KeyError, TypeError):
            return (f"the ParaView set in {self.directory} is locked ({self.path} exists); if "
                    f"no amfe run is writing it, remove the lock: {rm}")
        if host != host_name():
            return (f"the ParaView set in {self.directory} is being written by another amfe run "
                    f"(pid {pid} on host {host}); wait for it to end, or give another --vtu "
                    f"DIR; if it is dead, remove the lock: {rm}")
        if pid_running(pid):
            return (f"the ParaView set in {self.directory} is being written by another amfe run "
                    f"(pid {pid}); wait for it to end, or give another --vtu DIR")
        return (f"stale lock {self.path}: the amfe run that took it (pid {pid}) has ended "
                f"without removing it (killed?); remove the lock and run again: {rm}")


def clear_stale_sets(directory, written):
    """After ``--bc all`` wrote the subsets ``written`` of ``directory``: remove an older
    top-level set of amfe's in it and its subsets of amfe's not written now (another bed's
    ``periodic/``), so that ``amfe view`` cannot render them. Returns the removed paths."""
    directory = os.fspath(directory)
    gone = [os.path.join(directory, n) for n in remove_set(directory)]
    for sub in SUBSETS:
        if sub not in written and os.path.isdir(os.path.join(directory, sub)):
            gone += [os.path.join(directory, sub, n)
                     for n in remove_set(os.path.join(directory, sub))]
    return gone
