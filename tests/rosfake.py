"""A ROS 2 node without ROS: a fake libtracetools.so per distro and a stand-in node in C, built once per test session.

What is built (gcc, into a temporary folder; tests that need it skip, saying why, where gcc is missing):

- per distro of ``DISTROS`` (Humble, Jazzy, Rolling: the vendored headers of tests/programs/tracetools/<distro>,
  whose README says where each came from):
  - ``libtracetools.so``, a fake generated from that header's declaration blocks (``DECLARE_TRACEPOINT`` on Humble,
    ``_DECLARE_TRACEPOINT`` from Iron on) by ``declarations`` and ``fake_source``, so it defines every function the
    header declares and the compiler checks each definition against the declaration.  Each ``ros_trace_X``, and from
    Iron on each ``ros_trace_do_X``, is a no-op that counts its calls, as the real library is with no tracing session;
    ``ros_trace_enabled_X`` (counted too) is true only while ``FAKE_TRACETOOLS_SESSION`` is set in the environment (a
    simulated ``ros2 trace``); ``ros_trace_compile_status()`` is false.  It also exports the counters:
    ``size_t fake_tracetools_size(void)``, ``const char *fake_tracetools_name(size_t i)`` and ``unsigned long long
    fake_tracetools_count(const char *name)``, where a name is the function's without ``ros_trace_``
    (``"callback_start"``, ``"enabled_rclcpp_callback_register"``, ``"do_rclcpp_callback_register"``; 0 for a name it
    does not have).
  - ``rosnode``, the stand-in node (tests/programs/rosnode.c; its header comment lists its options and its JSON line),
    compiled against that header and linked to that fake (``-ltracetools``, no rpath: it runs with the ``env`` below,
    as a ROS 2 node runs with setup.bash's LD_LIBRARY_PATH), with ``-rdynamic`` as ament links every node that uses
    tracetools.
  - ``rosnode-definer``, the same node built with ``-DEXISTING_DEFINER``: its executable itself exports a
    ``ros_trace_callback_start`` that does not forward (an "existing definer"); its JSON line has ``definer_calls``.
- ``disabled``: the stand-in built against the Jazzy header with the ``disabled`` config.h (``TRACETOOLS_DISABLED``:
  every tracepoint compiled out, no fake linked), linked instead to a stub ``librclcpp.so``
  (tests/programs/rclcpp_stub.c) that it maps at run time, as a node of a ROS 2 built with TRACETOOLS_DISABLED does.

The API (stable: other tests build on it)::

    from rosfake import RosFake, build

    @pytest.fixture(scope="session")
    def ros(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
        return build(tmp_path_factory)  # built once per session, however many modules ask

    ros.distros["jazzy"].node          # the stand-in's path; .definer, .lib (the fake), .libdir, .include
    ros.distros["jazzy"].env           # what to add to the environment: {"LD_LIBRARY_PATH": libdir}
    ros.distros["jazzy"].environ()     # os.environ with that added (pass extra=... for more)
    ros.distros["jazzy"].run("--count", "5")   # -> NodeRun: .lines (each JSON line, parsed), .main, .returncode
    ros.disabled                       # a Distro as well: .lib is None, .libdir holds librclcpp.so

``build_into(folder)`` builds the same without pytest (for bench/ scripts); ``declarations(header_text)`` is the parser.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Optional

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PROGRAMS = os.path.join(REPO, "tests", "programs")
HEADERS = os.path.join(PROGRAMS, "tracetools")
DISTROS = ("humble", "jazzy", "rolling")
SESSION_ENV = "FAKE_TRACETOOLS_SESSION"
CFLAGS = ("-O2", "-Wall", "-Wextra", "-Wno-unused-parameter", "-Werror")

_OPENING = re.compile(r"^_?DECLARE_TRACEPOINT\(", re.MULTILINE)
_COMMENT = re.compile(r"/\*.*?\*/|//[^\n]*", re.DOTALL)
_PARAMETER = re.compile(r"^(?P<type>.*?[\s*])(?P<name>\w+)$")


@dataclass(frozen=True)
class Declaration:
    """One ``DECLARE_TRACEPOINT(name, params...)`` block: the event's name and its parameters, as written."""

    name: str
    parameters: tuple[tuple[str, str], ...]  # (type, name), e.g. ("const void *", "callback")

    def signature(self) -> str:
        """The parameter list of its C functions: ``const void * callback, const bool is_intra_process``; ``void``."""
        return ", ".join(f"{type_} {name}" for type_, name in self.parameters) or "void"


def declarations(header: str) -> list[Declaration]:
    """Every declaration block of a tracetools.h, in order: the text from each line-initial ``DECLARE_TRACEPOINT(`` or
    ``_DECLARE_TRACEPOINT(`` to its matching parenthesis, split at its top-level commas (no parameter type of the
    header holds a comma or a parenthesis, which the split relies on and which a test checks on every vendored one)."""
    found = []
    for opening in _OPENING.finditer(header):
        depth, at = 1, opening.end()
        while depth:
            depth += {"(": 1, ")": -1}.get(header[at], 0)
            at += 1
        body = " ".join(_COMMENT.sub(" ", header[opening.end() : at - 1]).split())
        name, *params = (part.strip() for part in body.split(","))
        parameters = []
        for param in params:
            match = _PARAMETER.match(param)
            if match is None:
                raise ValueError(f"tracepoint {name}: cannot split the parameter {param!r} into a type and a name")
            parameters.append((" ".join(match["type"].split()), match["name"]))
        found.append(Declaration(name, tuple(parameters)))
    return found


def has_enabled_do(header: str) -> bool:
    """Whether the header's declaration macro also declares ``ros_trace_enabled_X`` and ``ros_trace_do_X`` (Iron on)."""
    return "ros_trace_enabled_ ## event_name" in header


def exported_names(header: str) -> list[str]:
    """The names the fake counts under, in its order: every function it defines, without ``ros_trace_``."""
    names = ["compile_status"]
    for declaration in declarations(header):
        names.append(declaration.name)
        if has_enabled_do(header):
            names += [f"enabled_{declaration.name}", f"do_{declaration.name}"]
    return names


def fake_source(header: str, origin: str) -> str:
    """The C source of the fake libtracetools.so for a header's text (see the module docstring)."""
    names = exported_names(header)
    index = {name: i for i, name in enumerate(names)}
    count = "atomic_fetch_add_explicit(&counts[{}], 1, memory_order_relaxed);"
    lines = [
        f"/* Generated by tests/rosfake.py from {origin}: every function it declares, counting its calls. */",
        "#include <stdatomic.h>",
        "#include <stdlib.h>",
        "#include <string.h>",
        '#include "tracetools/tracetools.h"',
        "",
        f"static const char *const names[{len(names)}] = {{{', '.join(json.dumps(n) for n in names)}}};",
        f"static atomic_ullong counts[{len(names)}];",
        "",
        f"TRACETOOLS_PUBLIC size_t fake_tracetools_size(void) {{ return {len(names)}; }}",
        f"TRACETOOLS_PUBLIC const char *fake_tracetools_name(size_t i) {{ return i < {len(names)} ? names[i] : NULL; }}",
        "TRACETOOLS_PUBLIC unsigned long long fake_tracetools_count(const char *name) {",
        f"  for (size_t i = 0; i < {len(names)}; i++)",
        "    if (!strcmp(names[i], name)) return atomic_load_explicit(&counts[i], memory_order_relaxed);",
        "  return 0;",
        "}",
        "",
        f"bool ros_trace_compile_status(void) {{ {count.format(index['compile_status'])} return false; }}",
    ]
    for declaration in declarations(header):
        name, params = declaration.name, declaration.signature()
        lines.append(f"void ros_trace_{name}({params}) {{ {count.format(index[name])} }}")
        if has_enabled_do(header):
            session = f"return getenv({json.dumps(SESSION_ENV)}) != NULL;"
            lines.append(f"bool ros_trace_enabled_{name}(void) {{ {count.format(index['enabled_' + name])} {session} }}")
            lines.append(f"void ros_trace_do_{name}({params}) {{ {count.format(index['do_' + name])} }}")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class NodeRun:
    """One run of the stand-in: its exit status, its output and each JSON line it printed (a forked child prints one)."""

    returncode: int
    stdout: str
    stderr: str
    lines: tuple[dict[str, Any], ...]

    @property
    def main(self) -> dict[str, Any]:
        """The line of the process that was started (``"role": "main"``)."""
        return next(line for line in self.lines if line["role"] == "main")

    def callback(self, name: str) -> dict[str, Any]:
        """The main line's entry of a callback by name (``timer0``, ``subscription``, ``nested``, ``stuck``, ``many``)."""
        return next(cb for cb in self.main["callbacks"] if cb["name"] == name)


@dataclass(frozen=True)
class Distro:
    """What was built for one distro's header (or for ``disabled``), and how to run it."""

    name: str
    include: tuple[str, ...]  # the -I folders, in order
    libdir: str  # LD_LIBRARY_PATH for the node: the fake libtracetools.so, or (disabled) the stub librclcpp.so
    lib: Optional[str]  # the fake libtracetools.so; None for disabled
    node: str
    definer: Optional[str]  # the node with its own non-forwarding ros_trace_callback_start; None for disabled
    header: str  # the tracetools.h it was built against

    @property
    def env(self) -> dict[str, str]:
        """What the node needs added to its environment."""
        return {"LD_LIBRARY_PATH": self.libdir}

    def environ(self, extra: Optional[Mapping[str, str]] = None, base: Optional[Mapping[str, str]] = None) -> dict[str, str]:
        """``base`` (os.environ) with the node's library folder first on LD_LIBRARY_PATH, then ``extra``."""
        env = dict(os.environ if base is None else base)
        env["LD_LIBRARY_PATH"] = os.pathsep.join(p for p in (self.libdir, env.get("LD_LIBRARY_PATH", "")) if p)
        env.update(extra or {})
        return env

    def run(self, *args: str, program: Optional[str] = None, extra_env: Optional[Mapping[str, str]] = None, timeout: float = 20) -> NodeRun:
        """Run the stand-in (or ``program``, e.g. ``self.definer``) to its end and parse its JSON lines."""
        done = subprocess.run(
            [program or self.node, *args], env=self.environ(extra_env), capture_output=True, text=True, timeout=timeout, check=False
        )
        lines = tuple(json.loads(line) for line in done.stdout.splitlines() if line.startswith("{"))
        return NodeRun(done.returncode, done.stdout, done.stderr, lines)


@dataclass(frozen=True)
class RosFake:
    """Everything built: the three distros' fakes and stand-ins, and the ``disabled`` build."""

    root: str
    distros: dict[str, Distro]
    disabled: Distro


def _gcc(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(["gcc", *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait(jobs: list[subprocess.Popen[str]]) -> None:
    failed = [(job.args, out) for job in jobs for out in [job.communicate()[0]] if job.returncode]
    if failed:
        raise RuntimeError("gcc failed:\n" + "\n".join(f"{' '.join(map(str, args))}\n{out}" for args, out in failed))


def build_into(root: str) -> RosFake:
    """Generate and compile everything into ``root`` (created), each distro in a folder of its own; gcc runs in parallel."""
    node_src = os.path.join(PROGRAMS, "rosnode.c")
    distros: dict[str, Distro] = {}
    libs = []
    for name in DISTROS:
        folder = os.path.join(root, name)
        os.makedirs(folder, exist_ok=True)
        header = os.path.join(HEADERS, name, "tracetools", "tracetools.h")
        with open(header, encoding="utf-8") as handle:
            source = fake_source(handle.read(), f"tests/programs/tracetools/{name}/tracetools/tracetools.h")
        fake_c = os.path.join(folder, "fake_tracetools.c")
        with open(fake_c, "w", encoding="utf-8") as handle:
            handle.write(source)
        include = (os.path.join(HEADERS, name),)
        lib = os.path.join(folder, "libtracetools.so")
        libs.append(_gcc(*CFLAGS, "-shared", "-fPIC", "-I", include[0], "-o", lib, fake_c))
        distros[name] = Distro(name, include, folder, lib, os.path.join(folder, "rosnode"), os.path.join(folder, "rosnode-definer"), header)
    disabled_dir = os.path.join(root, "disabled")
    os.makedirs(disabled_dir, exist_ok=True)
    stub = os.path.join(PROGRAMS, "rclcpp_stub.c")
    libs.append(_gcc(*CFLAGS, "-shared", "-fPIC", "-o", os.path.join(disabled_dir, "librclcpp.so"), stub))
    _wait(libs)
    nodes = []
    for d in distros.values():
        common = (*CFLAGS, "-pthread", "-rdynamic", "-I", d.include[0], node_src, "-L", d.libdir, "-ltracetools")
        nodes.append(_gcc("-o", d.node, *common))
        nodes.append(_gcc("-DEXISTING_DEFINER", "-o", str(d.definer), *common))
    disabled_include = (os.path.join(HEADERS, "disabled"), os.path.join(HEADERS, "jazzy"))
    disabled = Distro(
        "disabled", disabled_include, disabled_dir, None, os.path.join(disabled_dir, "rosnode"), None, distros["jazzy"].header
    )
    includes = [arg for folder in disabled_include for arg in ("-I", folder)]
    link = ("-L", disabled_dir, "-Wl,--no-as-needed", "-lrclcpp")  # mapped although nothing of it is called
    nodes.append(_gcc(*CFLAGS, "-Wno-unused", "-pthread", "-rdynamic", *includes, "-o", disabled.node, node_src, *link))
    _wait(nodes)
    return RosFake(root, distros, disabled)


_built: dict[str, RosFake] = {}


def build(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
    """``build_into`` a session's temporary folder, once per session; skips the test, saying why, without gcc."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc is missing: the fake libtracetools and the stand-in ROS 2 node are compiled with it")
    if "session" not in _built:
        _built["session"] = build_into(str(tmp_path_factory.mktemp("rosfake")))
    return _built["session"]
