from setuptools import find_packages, setup

package_name = "fpp_msgs_py"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="FPP sensor team",
    maintainer_email="fpp@example.com",
    description="numpy <-> sensor_msgs helpers for the fringe-projection sensor",
    license="Apache-2.0",
)
