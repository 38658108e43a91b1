"""Where a program's memory cgroup goes: the runner's own memory cgroup found from /proc text (pure), v2 before v1."""

from __future__ import annotations

from runner.run.memcg import Hierarchy, locate

# This project's VM: cgroup v1 controllers, one of them memory, and an empty v2 hierarchy beside them (systemd's hybrid).
HYBRID_MOUNTS = """\
25 30 0:22 / /sys/fs/cgroup ro,nosuid - tmpfs tmpfs ro,mode=755
26 25 0:23 / /sys/fs/cgroup/unified rw,nosuid - cgroup2 cgroup2 rw,nsdelegate
27 25 0:24 / /sys/fs/cgroup/systemd rw,nosuid - cgroup cgroup rw,xattr,name=systemd
31 25 0:28 / /sys/fs/cgroup/memory rw,nosuid - cgroup cgroup rw,memory
32 25 0:29 / /sys/fs/cgroup/cpu,cpuacct rw,nosuid - cgroup cgroup rw,cpu,cpuacct
"""
HYBRID_CGROUP = "9:name=systemd:/\n4:memory:/process_api/292e\n1:cpu,cpuacct:/\n0::/\n"

# A unified machine (systemd, Debian 12 and later).
UNIFIED_MOUNTS = "30 1 0:26 / /sys/fs/cgroup rw,nosuid,nodev,noexec - cgroup2 cgroup2 rw,nsdelegate,memory_recursiveprot\n"
UNIFIED_CGROUP = "0::/user.slice/user-1000.slice/session-3.scope\n"


def test_a_hybrid_machine_offers_its_v2_hierarchy_first_and_its_v1_memory_hierarchy_second():
    assert locate(HYBRID_MOUNTS, HYBRID_CGROUP) == [
        Hierarchy(2, "/sys/fs/cgroup/unified"),
        Hierarchy(1, "/sys/fs/cgroup/memory/process_api/292e"),
    ]


def test_a_unified_machine_has_the_runners_cgroup_under_the_one_mount():
    assert locate(UNIFIED_MOUNTS, UNIFIED_CGROUP) == [Hierarchy(2, "/sys/fs/cgroup/user.slice/user-1000.slice/session-3.scope")]


def test_a_mount_of_a_sub_tree_shows_the_cgroups_below_its_root_and_no_other():
    # a container: the host's /docker/abc is mounted as its /sys/fs/cgroup
    mounts = "40 35 0:26 /docker/abc /sys/fs/cgroup rw - cgroup2 cgroup2 rw\n"
    assert locate(mounts, "0::/docker/abc/app\n") == [Hierarchy(2, "/sys/fs/cgroup/app")]
    assert locate(mounts, "0::/docker/other\n") == []


def test_no_memory_controller_and_nonsense_give_nothing():
    v1_without_memory = "32 25 0:29 / /sys/fs/cgroup/cpu rw - cgroup cgroup rw,cpu\n"
    assert locate(v1_without_memory, "1:cpu:/\n") == []
    assert locate("garbage\n- -\n", "x\n::\n") == []


def test_the_files_read_are_those_of_the_hierarchys_version():
    v1, v2 = Hierarchy(1, "/a"), Hierarchy(2, "/b")
    assert (v1.limit_file, v1.peak_file, v1.events_file) == ("memory.limit_in_bytes", "memory.max_usage_in_bytes", "memory.oom_control")
    assert (v2.limit_file, v2.peak_file, v2.events_file) == ("memory.max", "memory.peak", "memory.events")
