"""The checks said before any epoch on the splits a run trains and validates on (:mod:`seqnet.train.route`)."""

from seqnet.train.config import TrainConfig
from seqnet.train.route import holds_test_queries


def test_a_train_or_val_range_inside_the_test_split_is_said_before_training(synth_dataset):
    """--val-split A:B or --train-split A:B over test queries (240:300 style) was not said at train time (only the
    name test was); each is one line naming the overlap and a split apart from test. The dataset's own disjoint
    splits stay silent."""
    ds = synth_dataset  # queries: train 0:105, val 105:141, test 141:197
    assert holds_test_queries(ds, TrainConfig()) == []
    assert holds_test_queries(ds, TrainConfig(val_split="150:190")) == [
        "--val-split 150:190 holds 40 of the 56 queries of the test split 'test' (141:197): choosing the epoch on "
        "them makes its test numbers optimistic (hint: --val-split val)"]
    assert holds_test_queries(ds, TrainConfig(train_split="0:160", val_split="none")) == [
        "--train-split 0:160 holds 19 of the 56 queries of the test split 'test' (141:197): the model trains on "
        "them, so its test numbers are not a test (hint: --train-split train)"]
    assert holds_test_queries(ds, TrainConfig(val_split="test")) == [
        "--val-split test: choosing the epoch on the test split makes its test numbers optimistic (hint: "
        "--val-split val)"]
    said = holds_test_queries(ds, TrainConfig(train_split="all"))
    assert said == ["--train-split all (queries 0:197) holds 56 of the 56 queries of the test split 'test' "
                    "(141:197): the model trains on them, so its test numbers are not a test (hint: --train-split "
                    "train)"], said
