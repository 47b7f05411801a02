"""research/policy_behaviour.py on the scripted expert, whose grasp is known: it closes
across the tail, lifts the plug off the table and inserts it."""

from argparse import Namespace


def test_the_expert_grasps_across_the_tail_and_carries_the_plug(load_benchmark):
    script = load_benchmark("policy_behaviour")
    args = Namespace(
        policy="scripted",
        connector="ethernet",
        robot="ur5",
        num_envs=1,
        seed=0,
        window=1,  # one row per step
        threads=1,
    )
    windows = script.run(args)
    assert [w["step"] for w in windows] == list(range(1, 481))
    # The last step is not measured: the vector environment's autoreset has already replaced
    # that episode's state with the next one's.
    steps = [w for w in windows if "held" in w]
    assert len(steps) == 479 and "held" not in windows[-1]
    first_touch = next(k for k, w in enumerate(steps) if w["touch"])
    # Before the grasp: the plug lies on the table (its tip a few mm up), nothing is held.
    assert all(w["held"] == 0.0 and 0.0 < w["tip_mm"] < 15.0 for w in steps[:first_touch])
    held = [w for w in steps if w["held"]]
    assert len(held) > 50
    # While held: the fingers close across the tail, at its grasp point.
    assert all(w["cross_deg"] > 80.0 and w["grasp_mm"] < 15.0 for w in held)
    assert max(w["tip_mm"] for w in held) > 50.0  # lifted
    assert all(w["fixture"] == 0.0 for w in steps)  # it never runs into the port or stand
    assert steps[-1]["reach"] == 1.0 and steps[-1]["insert"] == 1.0
