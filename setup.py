"""Package discovery (the rest of the metadata is in pyproject.toml): every package under
clrender/ (a new method's subpackage ships without editing a list) and its data folders
(the ablation TOMLs: namespace packages, so setuptools ships them without warning), plus
kernels/ at the top of the repository installed as clrender.kernels."""
from setuptools import find_namespace_packages, setup

setup(packages=find_namespace_packages(include=["clrender", "clrender.*"],
                                       exclude=["*.__pycache__", "clrender.kernels"])
      + ["clrender.kernels"],
      package_dir={"clrender.kernels": "kernels"})
