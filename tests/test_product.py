"""The product is defined once (msfsu_bringup/product.yaml): the deployment profiles start it by default and the
benchmark's default agent drives it; this fails as soon as the two differ."""

import subprocess
import sys

import pytest

from msfsu_bringup.launcher import ProfileError, load_profile, profile_path
from msfsu_bringup.product import PRODUCT_FILE, load_product
from msfsu_evaluation.closed_loop.cli import build_parser, parse_agents

# the aeb node's parameters a profile sets from the camera and the checkpoint, not from the product
CAMERA_AND_CROP = {"use_sim_time", "crop_top_fraction", "publish_stage_times"}


def nodes(profile: str, **given: str) -> dict:
    _, specs = load_profile(profile_path(profile), {"bag": "bags/sample", **given} if profile == "replay" else given)
    return {spec.name: spec for spec in specs}


@pytest.mark.parametrize("profile", ["agent", "sim", "replay", "carla"])
def test_each_deployment_profile_starts_the_product_by_default(profile):
    product = load_product()
    graph = nodes(profile)
    assert graph["perception"].parameters["checkpoint"] == str(product.checkpoint)
    assert ("aeb" in graph) == product.aeb
    brake = {key: value for key, value in graph["aeb"].parameters.items()
             if key not in CAMERA_AND_CROP and not key.startswith("camera_")}  # the car's camera is the profile's
    assert brake == product.aeb_parameters
    if profile == "agent":
        assert (graph["perception"].parameters["backend"], graph["perception"].parameters["precision"]) == (
            product.backend, product.precision)
    assert "aeb" not in nodes(profile, aeb="false")  # the network alone, on request


def test_the_benchmarks_default_agent_is_the_agent_profile_the_benchmark_starts():
    """What msfsu-benchmark --checkpoint <the product's> drives is the agent profile with its defaults: the brake, its
    parameters, the backend and precision (GraphAgent hands the agent's configuration to that profile)."""
    product = load_product()
    options = build_parser().parse_args(["--checkpoint", f"msfsu={product.checkpoint}", "--no-expert", "--out", "x"])
    (agent,) = parse_agents(options)
    graph = nodes("agent")
    assert agent.aeb == ("aeb" in graph) and (agent.backend, agent.precision) == (
        graph["perception"].parameters["backend"], graph["perception"].parameters["precision"])
    profile_brake = {key: value for key, value in graph["aeb"].parameters.items() if key not in CAMERA_AND_CROP}
    from msfsu_control.aeb import AebConfig

    assert agent.aeb_crossing == profile_brake.get("predict_crossing", AebConfig().predict_crossing)
    assert dict(agent.aeb_parameters) == {k: v for k, v in profile_brake.items() if k != "predict_crossing"}


def test_a_field_of_the_product_is_printed_for_the_makefile_and_scripts():
    run = subprocess.run([sys.executable, "-m", "msfsu_bringup.product", "checkpoint"], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == str(load_product().checkpoint)


def test_a_profile_naming_no_field_of_the_product_is_refused(tmp_path):
    profile = tmp_path / "mine.yaml"
    profile.write_text("arguments: {checkpoint: {product: weights}}\nnodes: []\n")
    with pytest.raises(ProfileError, match="argument checkpoint: the product has no 'weights'"):
        load_profile(profile, {})
    assert PRODUCT_FILE.is_file()
