from setuptools import find_packages, setup

package_name = "fpp_nodes"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    package_data={"fpp_nodes": ["data/*.yaml", "data/models/*.onnx", "data/models/*.yaml"]},
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="FPP sensor team",
    maintainer_email="fpp@example.com",
    description="Fringe projection profilometry core and offline tool",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "fpp = fpp_nodes.cli:main",
            "pattern_projector = fpp_nodes.nodes.pattern_projector:main",
            "projector_display = fpp_nodes.nodes.projector_display:main",
            "fringe_camera_sim = fpp_nodes.nodes.fringe_camera_sim:main",
            "capture_sequence = fpp_nodes.nodes.capture_sequence:main",
            "fpp_depth = fpp_nodes.nodes.fpp_depth:main",
            "sensor = fpp_nodes.nodes.sensor:main",
            "cnn_depth = fpp_nodes.nodes.cnn_depth:main",
            "demo = fpp_nodes.nodes.demo:main",
            "record = fpp_nodes.nodes.record:main",
            "replay = fpp_nodes.nodes.replay:main",
        ],
    },
)
