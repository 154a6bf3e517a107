"""The ``file`` problem's surface defaults on a raw input mesh a user did not make for us."""

import numpy as np
import pytest
import trimesh

from willmore_nlp import FlowError, registry


def test_raw_capsule_takes_its_first_step_within_the_file_problems_retries(tmp_path) -> None:
    """A trimesh capsule (count 16 x 16, 258 v, noise 1 % of the radius, min angle 9.3 deg) needs its first step
    far below h: with the flow's default 4 retries every attempt from h to h/16 fails (the first-step budget or a
    collapsed edge) and the run stops; the ``file`` problem's ``max_retries = 8`` takes it at h/128 (measured: 7
    retries, 16 iterations), and the adaptive steps then grow again (back at h by step 19 of a 20-step run)."""
    capsule = trimesh.creation.capsule(height=1.0, radius=0.5, count=[16, 16])
    capsule.vertices += 0.01 * np.random.default_rng(3).standard_normal(capsule.vertices.shape)
    capsule.export(tmp_path / "capsule.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "capsule.obj"))
    assert pb.flow_options["max_retries"] == 8
    with pytest.raises(FlowError, match="failed after 4 retries"):
        pb.make_flow(max_retries=4).step()
    flow = pb.make_flow()
    w0 = flow.discrete_energy(flow.X)
    first = flow.step()
    assert 4 < first.retries <= 8 and first.tau <= pb.tau / 2**5
    second = flow.step()
    assert second.retries == 0 and second.energy < first.energy < w0
