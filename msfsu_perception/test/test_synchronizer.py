from msfsu_perception.latest_slot import LatestSlot
from msfsu_perception.synchronizer import ApproximateTimeSynchronizer, Pair

MS = 1_000_000


def test_pairs_exact_and_approximate_stamps():
    sync = ApproximateTimeSynchronizer(queue_size=5, slop_ns=10 * MS)
    assert sync.add_a(100 * MS, "rgb0") is None
    assert sync.add_b(100 * MS, "d0") == Pair(100 * MS, "rgb0", "d0")
    assert sync.add_b(203 * MS, "d1") is None
    assert sync.add_a(200 * MS, "rgb1") == Pair(200 * MS, "rgb1", "d1")
    assert not sync.dropped


def test_mismatched_stamps_beyond_slop_are_not_paired():
    sync = ApproximateTimeSynchronizer(queue_size=5, slop_ns=10 * MS)
    assert sync.add_a(100 * MS, "rgb") is None
    assert sync.add_b(150 * MS, "depth") is None


def test_picks_closest_partner_and_drops_older_ones():
    sync = ApproximateTimeSynchronizer(queue_size=5, slop_ns=30 * MS)
    for stamp in (70, 90, 100):
        sync.add_b(stamp * MS, f"d{stamp}")
    assert sync.add_a(95 * MS, "rgb") == Pair(95 * MS, "rgb", "d90")  # 5 ms away, ties go to the older
    assert sync.dropped["unpaired_b"] == 1  # d70 can never pair in order
    assert sync.add_a(105 * MS, "rgb2") == Pair(105 * MS, "rgb2", "d100")


def test_duplicate_and_out_of_order_stamps_are_dropped_and_counted():
    sync = ApproximateTimeSynchronizer(queue_size=5, slop_ns=1 * MS)
    sync.add_a(100 * MS, "a")
    assert sync.add_a(100 * MS, "dup") is None
    assert sync.add_a(50 * MS, "late") is None
    assert sync.dropped == {"duplicate_stamp_a": 1, "out_of_order_stamp_a": 1}
    assert sync.add_b(100 * MS, "b") == Pair(100 * MS, "a", "b")


def test_queue_is_bounded():
    sync = ApproximateTimeSynchronizer(queue_size=3, slop_ns=0)
    for stamp in range(10):
        sync.add_a(stamp * MS, stamp)
    assert sync.dropped["unpaired_a"] == 7
    assert sync.add_b(9 * MS, "b") == Pair(9 * MS, 9, "b")


def test_clear_forgets_unpaired_items_and_last_stamps_and_keeps_the_counters():
    sync = ApproximateTimeSynchronizer(queue_size=5, slop_ns=1 * MS)
    sync.add_a(100 * MS, "old")
    sync.add_a(100 * MS, "dup")
    sync.clear()
    assert sync.add_b(100 * MS, "b") is None  # "old" is gone: nothing to pair with
    assert sync.add_a(50 * MS, "earlier") is None and "out_of_order_stamp_a" not in sync.dropped  # a new stream
    assert sync.dropped == {"duplicate_stamp_a": 1}


def test_latest_slot_keeps_only_the_newest_item():
    slot: LatestSlot[int] = LatestSlot()
    assert slot.take() is None
    assert slot.put(1) is None
    assert slot.put(2) == 1  # 1 was skipped
    assert slot.take() == 2
    assert slot.take() is None
