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
  - ``librclcpp.so``, a stub standing for rcl, the rmw layer and librclcpp together (``stub_sources``): it makes the
    tracepoint calls those libraries make from their own code (``LIBRARY_TRACEPOINTS``: the inits, the executor's,
    rcl's and rmw's publish and take), through the header's macro and its own PLT, linked to the fake.
  - ``rosnode``, the stand-in node (tests/programs/rosnode.c; its header comment lists its options and its JSON line),
    compiled against that header, calling the tracepoints rclcpp's header templates compile into a node (callbacks,
    callback_added, register, rclcpp_publish) itself and the others through the stub; linked to both (no rpath: it
    runs with the ``env`` below, as a ROS 2 node runs with setup.bash's LD_LIBRARY_PATH), with ``-rdynamic`` as ament
    links every node that uses tracetools.
  - ``rosnode-definer``, the same node built with ``-DEXISTING_DEFINER``: its executable itself exports a
    ``ros_trace_callback_start`` that does not forward (an "existing definer"); its JSON line has ``definer_calls``.
- ``disabled``, a ROS 2 built with TRACETOOLS_DISABLED: no libtracetools.so at all (tracetools is then an INTERFACE
  target); the stub librclcpp.so and the stand-in built against the Jazzy header with the ``disabled`` config.h, so no
  tracepoint is called, while the node still maps librclcpp.so: how the runner tells it from a program without ROS.
- ``disabled_node``, a node built with TRACETOOLS_DISABLED against a normal (Jazzy) ROS 2: it runs on Jazzy's stub
  librclcpp.so and fake, so the libraries' tracepoints fire but no callback's.

The API (stable: other tests build on it)::

    from rosfake import RosFake, build

    @pytest.fixture(scope="session")
    def ros(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
        return build(tmp_path_factory)  # built once per session, however many modules ask

    ros.distros["jazzy"].node          # the stand-in's path; .definer, .lib (the fake), .rclcpp, .libdir, .include
    ros.distros["jazzy"].env           # what to add to the environment: {"LD_LIBRARY_PATH": libdir}
    ros.distros["jazzy"].environ()     # os.environ without LD_PRELOAD, with that added; extra={"LD_PRELOAD": ...}
    ros.distros["jazzy"].run("--count", "5", extra_env={...})  # -> NodeRun: .lines (each JSON line), .main, .callback(name)
    ros.disabled, ros.disabled_node    # Distros as well; disabled.lib is None (its libdir has librclcpp.so only)

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


# The tracepoints that rcl, the rmw layer and librclcpp's own .cpp files call (notes-38 §1.4): the stub librclcpp.so
# makes these calls; the others are compiled into the node itself from rclcpp's header templates.
LIBRARY_TRACEPOINTS = (
    "rcl_init", "rcl_node_init", "rmw_publisher_init", "rcl_publisher_init", "rcl_service_init", "rcl_timer_init",
    "rclcpp_timer_link_node", "rmw_subscription_init", "rcl_subscription_init", "rclcpp_executor_get_next_ready",
    "rclcpp_executor_wait_for_work", "rclcpp_executor_execute", "rcl_publish", "rmw_publish", "rmw_take", "rcl_take",
    "rclcpp_take",
)  # fmt: skip


def stub_sources(header: str, origin: str) -> tuple[str, str]:
    """The C source and the header of the stub librclcpp.so for a tracetools.h: ``rclcpp_stub_X(params)`` calls the
    tracepoint X through the header's own macro, for each of ``LIBRARY_TRACEPOINTS``; ``rclcpp_stub_traced()`` says
    whether it was built with tracing (not with TRACETOOLS_DISABLED)."""
    by_name = {d.name: d for d in declarations(header)}
    prototypes = [f"void rclcpp_stub_{name}({by_name[name].signature()})" for name in LIBRARY_TRACEPOINTS]
    stub_h = "\n".join(
        [
            f"/* Generated by tests/rosfake.py from {origin}: the stub librclcpp.so's functions. */",
            "#include <stdbool.h>",
            "#include <stddef.h>",
            "#include <stdint.h>",
            "int rclcpp_stub_traced(void);",
            *(f"{prototype};" for prototype in prototypes),
        ]
    )
    stub_c = [
        f"/* Generated by tests/rosfake.py from {origin}: rcl's, rmw's and librclcpp's own tracepoint calls. */",
        '#include "tracetools/tracetools.h"',
        '#include "rclcpp_stub.h"',
        "#ifdef TRACETOOLS_TRACEPOINT",
        "#define RT_TP TRACETOOLS_TRACEPOINT",
        "#else",
        "#define RT_TP TRACEPOINT",
        "#endif",
        "#ifdef TRACETOOLS_DISABLED",
        "int rclcpp_stub_traced(void) { return 0; }",
        "#else",
        "int rclcpp_stub_traced(void) { return 1; }",
        "#endif",
    ]
    for name, prototype in zip(LIBRARY_TRACEPOINTS, prototypes):
        args = "".join(f", {param}" for _, param in by_name[name].parameters)
        stub_c.append(f"{prototype} {{ RT_TP({name}{args}); }}")
    return "\n".join(stub_c) + "\n", stub_h + "\n"


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
    """What was built for one distro's header (or for a ``disabled`` variant), and how to run it."""

    name: str
    include: tuple[str, ...]  # the -I folders of the tracetools header, in order
    libdir: str  # LD_LIBRARY_PATH for the node: its librclcpp.so and (unless the whole ROS is disabled) libtracetools.so
    lib: Optional[str]  # the fake libtracetools.so; None when the whole ROS is disabled (tracetools has no library then)
    rclcpp: str  # the stub librclcpp.so the node links
    node: str
    definer: Optional[str]  # the node with its own non-forwarding ros_trace_callback_start; None for the disabled ones
    header: str  # the tracetools.h it was built against

    @property
    def env(self) -> dict[str, str]:
        """What the node needs added to its environment."""
        return {"LD_LIBRARY_PATH": self.libdir}

    def environ(self, extra: Optional[Mapping[str, str]] = None, base: Optional[Mapping[str, str]] = None) -> dict[str, str]:
        """``base`` (os.environ) without LD_PRELOAD and with the node's library folder first on LD_LIBRARY_PATH, then
        ``extra`` (which may set LD_PRELOAD)."""
        env = {key: value for key, value in (os.environ if base is None else base).items() if key != "LD_PRELOAD"}
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
    """Everything built: the three distros, the whole-ROS ``disabled`` build and the ``disabled_node`` build."""

    root: str
    distros: dict[str, Distro]
    disabled: Distro
    disabled_node: Distro


def _gcc_all(commands: list[tuple[str, ...]]) -> None:
    """Run gcc once per argument list, all at once, and raise with gcc's words when any fails."""
    jobs = [subprocess.Popen(["gcc", *CFLAGS, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for args in commands]
    failed = [(args, out) for args, job in zip(commands, jobs) for out in [job.communicate()[0]] if job.returncode]
    if failed:
        raise RuntimeError("gcc failed:\n" + "\n".join(f"gcc {' '.join(args)}\n{out}" for args, out in failed))


def _write(path: str, text: str) -> str:
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text)
    return path


def _includes(folders: tuple[str, ...]) -> list[str]:
    return [arg for folder in folders for arg in ("-I", folder)]


def build_into(root: str) -> RosFake:
    """Generate and compile everything into ``root`` (created), a folder per variant; gcc runs in parallel, in three
    waves: the fakes, the stub librclcpp.so files (linked to them), the nodes."""
    node_src = os.path.join(PROGRAMS, "rosnode.c")
    jazzy_header = os.path.join(HEADERS, "jazzy", "tracetools", "tracetools.h")
    disabled_include = (os.path.join(HEADERS, "disabled"), os.path.join(HEADERS, "jazzy"))
    variants: dict[str, Distro] = {}
    for name in (*DISTROS, "disabled"):
        folder = os.path.join(root, name)
        os.makedirs(folder, exist_ok=True)
        header = jazzy_header if name == "disabled" else os.path.join(HEADERS, name, "tracetools", "tracetools.h")
        lib = None if name == "disabled" else os.path.join(folder, "libtracetools.so")
        include = disabled_include if name == "disabled" else (os.path.join(HEADERS, name),)
        definer = None if name == "disabled" else os.path.join(folder, "rosnode-definer")
        rclcpp = os.path.join(folder, "librclcpp.so")
        variants[name] = Distro(name, include, folder, lib, rclcpp, os.path.join(folder, "rosnode"), definer, header)
    node_dir = os.path.join(root, "disabled-node")
    os.makedirs(node_dir, exist_ok=True)
    jazzy = variants["jazzy"]
    disabled_node = Distro(
        "disabled-node", disabled_include, jazzy.libdir, jazzy.lib, jazzy.rclcpp, os.path.join(node_dir, "rosnode"), None, jazzy_header
    )
    waves: tuple[list[tuple[str, ...]], ...] = ([], [], [])
    for d in variants.values():
        with open(d.header, encoding="utf-8") as handle:
            text = handle.read()
        origin = os.path.relpath(d.header, REPO)
        stub_c, stub_h = stub_sources(text, origin)
        _write(os.path.join(d.libdir, "rclcpp_stub.h"), stub_h)
        stub = _write(os.path.join(d.libdir, "rclcpp_stub.c"), stub_c)
        flags = ("-shared", "-fPIC", *_includes(d.include), "-I", d.libdir)
        if d.lib is not None:
            waves[0].append((*flags, "-o", d.lib, _write(os.path.join(d.libdir, "fake_tracetools.c"), fake_source(text, origin))))
        tracetools = () if d.lib is None else ("-L", d.libdir, "-ltracetools")
        waves[1].append((*flags, "-o", d.rclcpp, stub, *tracetools))
        node = ("-pthread", "-rdynamic", *_includes(d.include), "-I", d.libdir, node_src, "-L", d.libdir, "-lrclcpp", *tracetools)
        if d.lib is None:
            node = ("-Wno-unused", *node)
        waves[2].append(("-o", d.node, *node))
        if d.definer is not None:
            waves[2].append(("-DEXISTING_DEFINER", "-o", d.definer, *node))
    node = (*_includes(disabled_include), "-I", jazzy.libdir, node_src, "-L", jazzy.libdir, f"-Wl,-rpath-link,{jazzy.libdir}", "-lrclcpp")
    waves[2].append(("-Wno-unused", "-pthread", "-rdynamic", "-o", disabled_node.node, *node))
    for wave in waves:
        _gcc_all(wave)
    return RosFake(root, {name: variants[name] for name in DISTROS}, variants["disabled"], disabled_node)


_built: dict[str, RosFake] = {}


def build(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
    """``build_into`` a session's temporary folder, once per session; skips the test, saying why, without gcc."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc is missing: the fake libtracetools and the stand-in ROS 2 node are compiled with it")
    if "session" not in _built:
        _built["session"] = build_into(str(tmp_path_factory.mktemp("rosfake")))
    return _built["session"]
