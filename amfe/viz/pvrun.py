"""Run ParaView's pvpython on the shipped view script (:mod:`amfe.viz.amfe_view_pv`).

Debian's pvpython (ParaView 5.11) aborts without an X server, even with
``--force-offscreen-rendering``, and works under ``xvfb-run``: so without
``$DISPLAY`` it runs as ``xvfb-run -a pvpython``, and when neither a display nor
xvfb-run is there, ParaView counts as missing (``amfe view`` falls back to
matplotlib).

(Not called paraview.py: pvpython puts the script's folder first on sys.path, and
``import paraview`` would then find this module.)
"""
import os
import random
import shutil
import subprocess
import sys

from amfe.viz.scene import COLOR_ARRAYS

SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "amfe_view_pv.py")
TIMEOUT_S = 300
X_ATTEMPTS = 3
"""Runs of pvpython when Xvfb refused the connection: on a loaded machine it now and then
does ("bad X server connection": 2 of about 20 runs here), and a failed start costs
about 3 s."""
INSTALL_HINT = "apt-get install paraview python3-paraview xvfb"


def paraview_command(environ=None):
    """The command prefix that runs pvpython here, or None when it cannot run.

    Parameters
    ----------
    environ : mapping, optional
        Environment to look in (default: ``os.environ``); ``PATH`` and ``DISPLAY`` count.

    Returns
    -------
    list of str or None
        ``[pvpython]`` with a display, ``[xvfb-run, -a, pvpython]`` without.
    """
    env = os.environ if environ is None else environ
    path = env.get("PATH", os.defpath)
    pv = shutil.which("pvpython", path=path)
    if pv is None:
        return None
    if env.get("DISPLAY"):
        return [pv]
    xvfb = shutil.which("xvfb-run", path=path)
    return [xvfb, "-a", pv] if xvfb else None


def _with_server_number(cmd):
    """xvfb-run -a starts its search at a random display number: two runs that start
    together (``-a`` alone begins at 99 for both) would otherwise share one X server,
    and pvpython aborts with "bad X server connection" when the other one exits."""
    if len(cmd) > 2 and cmd[1] == "-a":
        return [cmd[0], "-a", "-n", str(random.randrange(100, 30000))] + cmd[2:]
    return cmd


def run_pvpython(args, timeout=TIMEOUT_S):
    """``subprocess.run`` of a pvpython command line (``paraview_command() + [...]``) on an X
    server of its own, run again when Xvfb refused the connection (:data:`X_ATTEMPTS`)."""
    for _ in range(X_ATTEMPTS):
        proc = subprocess.run(_with_server_number(args), capture_output=True, text=True,
                              timeout=timeout)
        if "bad X server connection" not in proc.stdout + proc.stderr:
            break
    return proc


def _what_failed(output, lines=5):
    """ParaView's error lines from its output (not the stack trace), else the last lines."""
    text = [line.strip() for line in output.splitlines() if line.strip()]
    errors = [line for line in text if "ERR|" in line or "Error" in line]
    return "\n".join(errors[:lines] or text[-lines:])


def render(cmd, scene, png, size, state=None):
    """Run the view script for one :class:`~amfe.viz.scene.Scene`.

    Returns
    -------
    bool
        True when pvpython wrote the PNG; otherwise the reason is printed to
        stderr (the caller falls back or fails).
    """
    # pvpython writes a hidden temporary: a PNG left by an earlier run cannot pass for
    # this one's, and a reader never sees half a file.
    tmp = os.path.join(os.path.dirname(os.path.abspath(png)),
                       f".{os.path.basename(png)}.{os.getpid()}.png")
    args = cmd + [SCRIPT, scene.path, "--png", tmp, "--color", COLOR_ARRAYS[scene.color][0],
                  "--title", scene.title, "--label", scene.label,
                  "--range", repr(scene.vmin), repr(scene.vmax),
                  "--warp", repr(scene.warp), "--size", str(size[0]), str(size[1])]
    if state:
        args += ["--state", state]
    try:
        proc = run_pvpython(args)
        ok = proc.returncode == 0 and os.path.isfile(tmp) and os.path.getsize(tmp) > 0
        if ok:
            os.replace(tmp, png)
            for line in proc.stdout.splitlines():     # pvpython's own timing
                if line.startswith("seconds:"):
                    print("pvpython " + line, flush=True)
            return True
        print(f"amfe view: pvpython exited with status {proc.returncode}:\n"
              + _what_failed(proc.stdout + proc.stderr), file=sys.stderr)
    except (OSError, subprocess.TimeoutExpired) as exc:
        print(f"amfe view: pvpython failed ({exc})", file=sys.stderr)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return False
