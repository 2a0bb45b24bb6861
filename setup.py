"""Build configuration that pyproject.toml cannot express: the shipped scenes (scenes_usd/, which stays at
the top of the repository) installed as the package ``cisp_warp.scenes`` (see ``cisp_warp.demo``)."""

from setuptools import find_packages, setup

setup(
    packages=find_packages(include=["cisp_warp", "cisp_warp.*", "sim", "sim.*"]) + ["cisp_warp.scenes"],
    package_dir={"cisp_warp.scenes": "scenes_usd"},
    package_data={"cisp_warp.scenes": ["*.usda", "*.usd", "*.usdc", "*.exr", "*.png"]},
)
