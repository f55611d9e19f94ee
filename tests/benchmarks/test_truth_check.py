"""benchmarks.truth_check: the truth's place is the library's when it has it, else its nearest of the same suffix."""

import numpy as np
import pytest

from benchmarks.truth_check import true_location


class _Model:
    nodes = {1: [0.0, 0.0, 0.0], 2: [1.0, 0.0, 0.0], 3: [0.1, 0.0, 0.0], 4: [0.05, 0.0, 0.0]}

    def node_position(self, node):
        return np.asarray(self.nodes[node], float) if node in self.nodes else None


class _Patch:
    kind = "patch"

    def locations(self):
        return ["node 1 r1", "node 2 r2", "node 3 r2", "node 4 r1"]


def test_the_truths_own_location_when_the_library_has_it():
    assert true_location(_Model(), _Patch(), {"location": "node 2 r2", "xyz_m": [0.0, 0.0, 0.0]}) == "node 2 r2"


def test_else_the_nearest_location_of_the_same_radius():
    # node 4 r1 is nearer the truth's position, but a patch of radius 1: the truth's radius is 2
    got = true_location(_Model(), _Patch(), {"location": "node 9 r2", "xyz_m": [0.04, 0.0, 0.0]})
    assert got == "node 3 r2"
    assert true_location(_Model(), _Patch(), {"location": "node 9 r1", "xyz_m": [0.04, 0.0, 0.0]}) == "node 4 r1"


def test_a_model_node_position_is_preferred_to_the_datas():
    truth = {"location": "node 9 r2", "xyz_m": [0.1, 0.0, 0.0], "model_node_xyz_m": [0.9, 0.0, 0.0]}
    assert true_location(_Model(), _Patch(), truth) == "node 2 r2"


def test_no_location_of_the_kind_is_an_error_naming_it():
    with pytest.raises(ValueError, match="patch"):
        true_location(_Model(), _Patch(), {"location": "node 9 r3", "xyz_m": [0.0, 0.0, 0.0]})
