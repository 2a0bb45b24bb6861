"""Resource guards: what USD may open, and USD's parse in a step that cannot hang or exhaust the process.

USD reads every layer a stage pulls in (sublayers, references, payloads) as soon as it composes the
stage, and its parser trusts its input: a reference to a FIFO blocks ``Usd.Stage.Open`` forever, a
device such as ``/dev/zero`` is read until memory runs out, some malformed values make the text
parser's error message grow quadratically until the process aborts, and a corrupt crate file can
crash it. So before the stage is composed, :func:`check_layers`

1. walks the layer graph with ``Sdf`` (no composition): every asset a layer names as a sublayer,
   reference or payload is resolved against that layer and must be a regular file (a missing one is
   left to USD, which reports it as a composition error: the importer warns); each file at most
   ``MAX_LAYER_BYTES``, all of them at most ``MAX_TOTAL_BYTES``, at most ``MAX_LAYERS`` layers; a
   ``.usda`` must be UTF-8 text;
2. composes the stage once and counts its prims (instance proxies included): at most ``MAX_PRIMS``,
   so references that multiply each other (a prim that references two copies of a prim that
   references two copies ...) are refused before the importer traverses them;
3. does both, which parse every layer, in a child process with a memory cap, forked by a parse server
   of its own (a process that never composes a stage, see :class:`_Server`)
   (``RLIMIT_AS``: ``PARSE_MEMORY_BYTES`` plus ``PARSE_BYTES_PER_FILE_BYTE`` per byte of the files)
   and a deadline (``PARSE_SECONDS`` plus ``PARSE_SECONDS_PER_MB``): a parse that runs past it, dies
   of a signal or runs out of memory is a :class:`SceneError` naming the file.

The child parses; the caller then opens the stage itself (the files are parsed twice: the parse
costs about 0.1 s for the shipped scenes). A stage whose files have not changed since they passed
(same inode, size, mtime) is not walked again in the same process. Where ``os.fork`` does not exist the walk runs in-process
(the regular-file and size checks still hold; the deadline does not).
"""

from __future__ import annotations

import atexit
import json
import os
import resource
import select
import signal
import stat
import time

from pxr import Sdf, Tf

from ..errors import SceneError

MAX_LAYER_BYTES = 512 << 20  #: largest layer file USD may parse [bytes]
MAX_TOTAL_BYTES = 2 << 30  #: all layers of a stage together [bytes]
MAX_LAYERS = 10_000  #: layers a stage may pull in
MAX_PRIMS = 2_000_000  #: prims of the composed stage, instance proxies included
PARSE_SECONDS = 30.0  #: deadline of the guarded parse [s] ...
PARSE_SECONDS_PER_MB = 2.0  #: ... plus this per MB of layer files
PARSE_MEMORY_BYTES = 2 << 30  #: memory the parse may add to the process [bytes] ...
PARSE_BYTES_PER_FILE_BYTE = 40  #: ... plus this many bytes per byte of layer files (text -> Sdf specs)

_ARC_NAMES = ("referenceList", "payloadList")


def _describe(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe): reading it would block"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device: reading it need never end"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _arc_owner(layer: Sdf.Layer, asset: str) -> str | None:
    """Path of the prim spec in ``layer`` whose reference or payload names ``asset`` (None: a sublayer)."""
    if asset in list(layer.subLayerPaths):
        return None
    found: list[str] = []

    def visit(path):
        if found or not path.IsPrimPath() and not path.IsPrimVariantSelectionPath():
            return
        spec = layer.GetPrimAtPath(path)
        if spec is None:
            return
        for name in _ARC_NAMES:
            ops = getattr(spec, name, None)
            if ops is None:
                continue
            items = list(ops.explicitItems) + list(ops.prependedItems) + list(ops.appendedItems) + list(ops.addedItems)
            if any(getattr(item, "assetPath", None) == asset for item in items):
                found.append(str(path))
                return

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found[0] if found else None


def _check_file(path: str, layer_path: str | None, owner: str | None, asset: str | None) -> int:
    """Size of ``path`` after checking it is a regular file within ``MAX_LAYER_BYTES``."""
    where = dict(file=layer_path or path, prim=owner)
    what = f"asset '{asset}' (resolved to '{path}')" if asset else "the file"
    try:
        st = os.stat(path)
    except OSError as exc:
        raise SceneError(f"{what} cannot be read: {exc.strerror}", **where) from None
    if not stat.S_ISREG(st.st_mode):
        raise SceneError(f"{what} is {_describe(st.st_mode)}; a USD layer must be a regular file", **where)
    if st.st_size > MAX_LAYER_BYTES:
        raise SceneError(f"{what} has {st.st_size / 2**20:.0f} MiB, more than the {MAX_LAYER_BYTES >> 20} MiB "
                         "a layer may have", **where)
    return st.st_size


def _check_text(path: str) -> None:
    """A ``.usda`` layer must be UTF-8 (USD's parser quotes bad bytes in messages it cannot encode)."""
    with open(path, "rb") as f:
        head = f.read(8)
        if not head.startswith(b"#usda"):
            return
        data = head + f.read()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise SceneError(f"line {line}: byte {exc.start} is not valid UTF-8; a .usda layer is UTF-8 text",
                         file=path) from None


def _signature(path: str) -> list:
    st = os.stat(path)
    return [path, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_mode]


#: {root path: signatures of every layer file its last walk passed}: a stage opened again (the
#: animation's clock after load_usd) is not parsed a third time while none of its files changed.
_PASSED: dict[str, list] = {}


def _still_passed(root: str) -> bool:
    sigs = _PASSED.get(root)
    if not sigs:
        return False
    try:
        return all(_signature(s[0]) == s for s in sigs)
    except OSError:
        return False


def walk_layers(path: str) -> tuple[int, int, list]:
    """Parse ``path`` and every layer it names (sublayers, references, payloads) with ``Sdf``, checking
    each asset as the module docstring says; returns (layers, bytes, file signatures). Raises
    :class:`SceneError`."""
    root = os.path.abspath(path)
    total = _check_file(root, None, None, None)
    todo, seen, held = [root], {root}, []
    while todo:
        current = todo.pop()
        _check_text(current)
        try:
            layer = Sdf.Layer.FindOrOpen(current)
        except Tf.ErrorException as exc:
            from .stage import tf_reason

            raise SceneError(f"not a readable USD file ({tf_reason(exc)})", file=current) from None
        if layer is None:
            raise SceneError("USD could not open the file (not a USD file, truncated or unreadable)", file=current)
        held.append(layer)  # keep every layer open until the walk ends
        for asset in layer.GetCompositionAssetDependencies():
            if not asset or "[" in asset:  # package-relative (.usdz) paths are read from their package
                continue
            resolved = layer.ComputeAbsolutePath(asset)
            if not resolved or not os.path.lexists(resolved):
                continue  # missing: USD reports it as a composition error, the importer warns
            resolved = os.path.abspath(resolved)
            if resolved in seen:
                continue
            try:
                total += _check_file(resolved, current, None, asset)
            except SceneError as exc:
                raise SceneError(exc.reason, file=current, prim=_arc_owner(layer, asset)) from None
            if total > MAX_TOTAL_BYTES:
                raise SceneError(f"the layers the stage pulls in add up to more than {MAX_TOTAL_BYTES >> 20} MiB",
                                 file=root)
            seen.add(resolved)
            if len(seen) > MAX_LAYERS:
                raise SceneError(f"the stage pulls in more than {MAX_LAYERS} layers", file=root)
            todo.append(resolved)
    return len(seen), total, [_signature(p) for p in sorted(seen)]


def count_prims(path: str) -> int:
    """Compose ``path`` and count its prims up to ``MAX_PRIMS`` (then :class:`SceneError`)."""
    from pxr import Usd

    stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    if stage is None:
        raise SceneError("USD could not open the file (not a USD file, truncated or unreadable)", file=path)
    n = 0
    for _ in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate)):
        n += 1
        if n > MAX_PRIMS:
            raise SceneError(f"the composed stage has more than {MAX_PRIMS} prims (references or instances that "
                             "multiply each other?)", file=path)
    return n


def _vm_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


_LIMITS = ("MAX_LAYER_BYTES", "MAX_TOTAL_BYTES", "MAX_LAYERS", "MAX_PRIMS")


def _parse(request: dict) -> dict:
    """The guarded parse of one request, in a child of the parse server: the walk and the prim count,
    or the reason they failed, as a dict; sends ``{"phase": "compose"}`` between them."""
    for name in _LIMITS:  # the caller's limits (tests lower them)
        globals()[name] = request[name]
    path = request["path"]
    try:
        layers, nbytes, signatures = walk_layers(path)
        request["phase"]()
        prims = count_prims(path)
        return {"ok": True, "layers": layers, "bytes": nbytes, "prims": prims, "signatures": signatures}
    except SceneError as exc:
        return {"reason": exc.reason, "file": exc.file, "prim": exc.prim}
    except MemoryError:
        return {"reason": "parsing it ran out of memory"}
    except Tf.ErrorException as exc:
        from .stage import tf_reason

        return {"reason": f"not a readable USD file ({tf_reason(exc)})"}
    except Exception as exc:  # noqa: BLE001 - reported as the file's fault, by type and text
        return {"reason": f"USD failed to parse it ({type(exc).__name__}: {str(exc)[:300]})"}


def _run_child(request: dict) -> dict:
    """Fork a child that runs :func:`_parse` under the request's memory cap; wait for it until the
    request's deadline. Returns the child's answer, or ``{"timeout": phase}`` / ``{"crash": name,
    "phase": phase}``. Runs in the parse server, which has no threads that could hold a lock."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: parse, report JSON lines, leave without running any cleanup
        try:
            os.close(read_end)
            cap = _vm_bytes() + request["budget"]
            try:
                resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
            except (ValueError, OSError):
                pass
            request["phase"] = lambda: os.write(write_end, b'{"phase": "compose"}\n')
            os.write(write_end, json.dumps(_parse(request)).encode() + b"\n")
        finally:
            os._exit(0)
    os.close(write_end)
    chunks, t0 = [], time.monotonic()
    try:
        while True:
            left = request["deadline"] - (time.monotonic() - t0)
            if left <= 0.0:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                return {"timeout": True, "phase": b"phase" in b"".join(chunks)}
            ready, _, _ = select.select([read_end], [], [], min(left, 1.0))
            if ready:
                data = os.read(read_end, 1 << 16)
                if not data:
                    break
                chunks.append(data)
        _, status = os.waitpid(pid, 0)
    finally:
        os.close(read_end)
    lines = [ln for ln in b"".join(chunks).decode("utf-8", "replace").splitlines() if ln.strip()]
    if lines and "phase" not in lines[-1] and not os.WIFSIGNALED(status):
        return json.loads(lines[-1])
    name = signal.Signals(os.WTERMSIG(status)).name if os.WIFSIGNALED(status) else "no answer"
    return {"crash": name, "phase": len(lines) > 0}


def _serve() -> None:
    """The parse server's loop: one JSON request a line on stdin, one JSON answer a line on the
    original stdout (stdout itself goes to stderr, so nothing USD prints can break the protocol);
    ends at end of input, i.e. when its caller closes the pipe or exits."""
    import sys

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the caller's; the server ends with its pipe
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    answers.write("ready\n")
    for line in sys.stdin:
        answers.write(json.dumps(_run_child(json.loads(line))) + "\n")


class _Server:
    """The parse server, a process of its own started on first use (``python -c ... _serve()``).

    The parse children are forked from that server, never from the caller: the caller has USD's worker
    threads (and Warp's, BLAS's), and a thread that holds a lock at the moment of a fork leaves that
    lock held forever in the child. A child forked from a busy test process could so wait out its
    deadline on a well-formed file (seen in CI: two files of the malformed corpus 'did not finish
    within 30 s'). The server never composes a stage and never starts a thread."""

    STARTUP_SECONDS = 120.0  #: the server's start (Python, USD, Warp imports) on a loaded machine [s]

    def __init__(self):
        import subprocess
        import sys
        import threading

        self.lock = threading.Lock()
        code = "import sys, json; sys.path[:0] = json.loads(sys.argv[1]); from cisp_warp.usd.guard import _serve; _serve()"
        try:
            self.proc = subprocess.Popen([sys.executable, "-c", code, json.dumps(sys.path)], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True, bufsize=1, close_fds=True)
        except OSError as exc:
            raise SceneError(f"the USD parse helper process could not start ({sys.executable!r}: {exc.strerror})") \
                from None
        atexit.register(self.close)
        if self._read_line(self.STARTUP_SECONDS) != "ready":
            self.close()
            raise SceneError("the USD parse helper process did not start (run `python -c \"import "
                             "cisp_warp.usd.guard\"` to see why)")

    def _read_line(self, timeout: float) -> str | None:
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        line = self.proc.stdout.readline() if ready else ""
        return line.strip() or None

    def ask(self, request: dict) -> dict | None:
        """The server's answer to ``request``, or None when the server died or fell silent."""
        with self.lock:
            try:
                self.proc.stdin.write(json.dumps(request) + "\n")
                self.proc.stdin.flush()
            except (BrokenPipeError, OSError):
                return None
            line = self._read_line(request["deadline"] + 30.0)
            return json.loads(line) if line else None

    def close(self) -> None:
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()
            except OSError:
                pass
        try:
            self.proc.kill()
            self.proc.wait()
        except OSError:
            pass


_SERVER: _Server | None = None


def _ask_server(request: dict) -> dict:
    global _SERVER
    if _SERVER is None or _SERVER.proc.poll() is not None:
        _SERVER = _Server()
    answer = _SERVER.ask(request)
    if answer is None:  # the server died or hung: a fresh one serves the next request
        _SERVER.close()
        _SERVER = None
        answer = {"crash": "the parse helper process stopped", "phase": False}
    return answer


def check_layers(path: str) -> None:
    """Run :func:`walk_layers` and :func:`count_prims` on ``path`` in a child process with a deadline
    and a memory cap (see the module docstring); raises :class:`SceneError` naming the file when they
    fail in any way."""
    root = os.path.abspath(path)
    if _still_passed(root):
        return
    if not hasattr(os, "fork"):
        _PASSED[root] = walk_layers(path)[2]
        count_prims(path)
        return
    size = os.path.getsize(path)
    request = {"path": root, "deadline": PARSE_SECONDS + PARSE_SECONDS_PER_MB * size / 1e6,
               "budget": PARSE_MEMORY_BYTES + PARSE_BYTES_PER_FILE_BYTE * size}
    request.update({name: globals()[name] for name in _LIMITS})
    try:
        msg = _ask_server(request)
    except SceneError as exc:  # the helper itself failed: named with the file it was to check
        raise SceneError(exc.reason, file=path) from None
    if "timeout" in msg:
        if msg["phase"]:
            raise SceneError(f"composing the stage did not finish within {request['deadline']:.0f} s: its "
                             "references or instances multiply into far too many prims", file=path)
        raise SceneError(f"USD's parser did not finish within {request['deadline']:.0f} s: the file is malformed "
                         "(e.g. an array of the wrong shape that the parser cannot recover from) or far too large",
                         file=path)
    if "crash" in msg:
        step = "composing the stage" if msg["phase"] else "parsing it"
        raise SceneError(f"USD crashed {step} ({msg['crash']}; out of memory past {request['budget'] / 2**30:.1f} "
                         "GiB more, or a corrupt file)", file=path)
    if not msg.get("ok"):
        raise SceneError(msg["reason"], file=msg.get("file") or path, prim=msg.get("prim"))
    _PASSED[root] = msg["signatures"]
