"""vislam.h's VL_ABI_MEMBERS names every member of the API types it covers, in declaration order.

vl_abi_layout() hashes that list (with the configuration's and the counters' X-macro rows), and
vl_init refuses a caller whose hash differs from the library's. A member left out of the list would
be a member whose renaming or moving the check cannot see: this test reads the struct declarations
of the header and compares."""

import re

from conftest import REPO

HEADER = REPO / "core" / "include" / "vislam" / "vislam.h"

# The types a caller fills or reads; vl_counters_t comes from VL_COUNTERS, the configuration's
# table rows from VL_CONFIG_KEYS, and vl_estimator_t is opaque (sizes and capacity checked).
COVERED = ("vl_calibration_t", "vl_landmark_t", "vl_config_t", "vl_imu_sample_t", "vl_stereo_obs_t",
           "vl_stereo_frame_t", "vl_pose_t", "vl_counter_entry_t", "vl_work_t")

MEMBER = re.compile(r"^\s*[A-Za-z_][\w\s\*]*?[\s\*]([A-Za-z_]\w*)\s*(\[[^\]]*\])?\s*;")


def struct_members(text):
    """{type name: [member names in order]} for every `typedef struct { ... } name;` of the header."""
    out = {}
    for body, name in re.findall(r"typedef struct \{(.*?)\n\} (\w+);", text, re.S):
        body = re.sub(r"/\*.*?\*/", "", body, flags=re.S)  # comments, Doxygen markers included
        members = []
        for line in body.splitlines():
            if line.lstrip().startswith("#") or "VL_CONFIG_KEYS(" in line:
                continue  # the configuration's table rows: hashed from VL_CONFIG_KEYS itself
            m = MEMBER.match(line)
            if m:
                members.append(m.group(1))
        out[name] = members
    return out


def abi_members(text):
    """[(type, member)] of the VL_ABI_MEMBERS list, in order."""
    block = re.search(r"#define VL_ABI_MEMBERS\(X\)(.*?)\n\n", text, re.S).group(1)
    return re.findall(r"X\((\w+), (\w+)\)", block)


def test_every_member_of_the_covered_types_is_hashed_in_order():
    text = HEADER.read_text()
    structs = struct_members(text)
    listed = abi_members(text)
    for name in COVERED:
        assert name in structs, f"{name} not found in vislam.h"
        assert structs[name], f"no members parsed for {name}"
        in_list = [m for t, m in listed if t == name]
        assert in_list == structs[name], (
            f"{name}: VL_ABI_MEMBERS lists {in_list}, the struct declares {structs[name]}")
    assert {t for t, _ in listed} == set(COVERED), "VL_ABI_MEMBERS names a type this test does not check"


def test_the_parser_sees_a_missing_member():
    """The comparison can fail: a member added to a struct, a member left out of the list."""
    text = HEADER.read_text()
    grown = text.replace("    uint32_t innovation_rows;", "    uint32_t innovation_rows;\n    double extra_member;", 1)
    assert struct_members(grown)["vl_pose_t"][-1] == "extra_member"
    assert [m for t, m in abi_members(grown) if t == "vl_pose_t"][-1] == "innovation_rows"
    shrunk = re.sub(r"\n\s*X\(vl_work_t, rows\)[^\n]*", "", text, count=1)
    assert [m for t, m in abi_members(shrunk) if t == "vl_work_t"] != struct_members(text)["vl_work_t"]
