"""ament_python package quad_modelling (colcon build, or pip install for the CLI)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "quad_modelling"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml") + glob("config/*.json")),
        (f"share/{PACKAGE}/config/vehicles", glob("config/vehicles/*.yaml")),
        (f"share/{PACKAGE}/config/mappings", glob("config/mappings/*.yaml")),
        (f"share/{PACKAGE}/config/topic_maps", glob("config/topic_maps/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="quad_modelling developers",
    maintainer_email="quad-modelling@example.com",
    description="Quadrotor flight-dynamics modelling from flight data (ROS 2 Jazzy).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "quad-modelling = quad_modelling.cli:main",
            "replay = quad_modelling.node_entry:replay",
            "predictor = quad_modelling.node_entry:predictor",
            "greybox_predictor = quad_modelling.node_entry:greybox_predictor",
            "narx_predictor = quad_modelling.node_entry:narx_predictor",
            "evaluator = quad_modelling.node_entry:evaluator",
        ],
    },
)
