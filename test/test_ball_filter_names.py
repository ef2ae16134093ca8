"""perception's estimator keeps its names for the filter that moved to tt_prediction (a test
across packages: tt_perception depends on tt_prediction, so it cannot live in
tt_prediction's tests without a dependency cycle)."""

from tt_perception.estimator import BallFilter as PerceptionFilter
from tt_prediction.ball_filter import BallFilter


def test_ball_filter_keeps_perception_names():
    assert PerceptionFilter is BallFilter
