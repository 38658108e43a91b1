"""Build the native core (runner.run._probe); everything else is in pyproject.toml."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "runner.run._probe",
            sources=["runner/run/_probe.c"],
            extra_compile_args=["-O2", "-std=gnu11", "-Wall", "-Wextra", "-Wno-unused-parameter", "-Wno-missing-field-initializers"],
            libraries=["pthread"],
        )
    ]
)
