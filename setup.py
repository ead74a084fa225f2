"""Package discovery (the rest of the metadata is in pyproject.toml): every package under
clrender/ (a new method's subpackage ships without editing a list), plus kernels/ at the top
of the repository installed as clrender.kernels."""
from setuptools import find_packages, setup

setup(packages=find_packages(include=["clrender", "clrender.*"]) + ["clrender.kernels"],
      package_dir={"clrender.kernels": "kernels"})
