"""Build the native core (runner.run._probe: bindings, interp.c without Python, records.c), trace reader (runner.run._trace)
and the libtracetools interposer (runner.run._roscb: no Python at all, never imported, only LD_PRELOADed by path).

Everything else is in pyproject.toml.
"""

from setuptools import Extension, setup

FLAGS = ["-O2", "-std=gnu11", "-Wall", "-Wextra", "-Wno-unused-parameter", "-Wno-missing-field-initializers"]

setup(
    ext_modules=[
        Extension(
            "runner.run._probe",
            sources=["runner/run/_probe.c", "runner/run/interp.c", "runner/run/records.c"],
            depends=["runner/run/histogram.h", "runner/run/interp.h", "runner/run/records.h", "runner/run/roscb.h"],
            # interp.c's functions stay inside the module; a Py* call in interp.c (no Python.h) fails the build, not just warns
            extra_compile_args=[*FLAGS, "-fvisibility=hidden", "-Werror=implicit-function-declaration"],
            libraries=["pthread"],
        ),
        Extension(
            "runner.run._trace",
            sources=["runner/run/_trace.c"],
            depends=["runner/run/histogram.h"],
            extra_compile_args=FLAGS,
            libraries=["pthread"],
        ),
        Extension(
            "runner.run._roscb",
            sources=["runner/run/roscb.c"],
            depends=["runner/run/roscb.h"],
            # only the ros_trace_* hooks are exported (HOOK in roscb.c); a Py* call would be an undefined symbol at preload
            extra_compile_args=[*FLAGS, "-fvisibility=hidden", "-Werror=implicit-function-declaration"],
            extra_link_args=["-Wl,-z,defs"],
            libraries=["pthread", "dl"],
        ),
    ]
)
