"""Build the native core (runner.run._probe) and trace reader (runner.run._trace); everything else is in pyproject.toml."""

from setuptools import Extension, setup

FLAGS = ["-O2", "-std=gnu11", "-Wall", "-Wextra", "-Wno-unused-parameter", "-Wno-missing-field-initializers"]

setup(
    ext_modules=[
        Extension(
            "runner.run._probe",
            sources=["runner/run/_probe.c"],
            depends=["runner/run/histogram.h"],
            extra_compile_args=FLAGS,
            libraries=["pthread"],
        ),
        Extension(
            "runner.run._trace",
            sources=["runner/run/_trace.c"],
            depends=["runner/run/histogram.h"],
            extra_compile_args=FLAGS,
            libraries=["pthread"],
        ),
    ]
)
