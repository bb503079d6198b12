#!/usr/bin/python3
"""Which attributes a round trip through another format loses (bench/results/export.md).

Usage: bench/ply_trace.py WRITTEN.ply BACK.ply OUT_DIR

WRITTEN is the .ply `crpgs export` wrote, BACK the same scene converted to another format
(.spz, .sog) and read back as .ply. The Gaussians of BACK are matched to WRITTEN's by position
(a format may reorder them, .sog does), each attribute group's error is printed, and for each
group OUT_DIR/fix_<group>.ply is BACK with that group put back from WRITTEN. Rendering those
(`crpgs import OUT_DIR/fix_<group>.ply -c RUN/config.yaml`) shows what each group's loss costs.
Binary little-endian .ply files with float vertex properties only (what both tools write).
"""
import os
import sys

import numpy as np

GROUPS = {
    "position": ["x", "y", "z"],
    "scale": ["scale_0", "scale_1", "scale_2"],
    "rotation": ["rot_0", "rot_1", "rot_2", "rot_3"],
    "opacity": ["opacity"],
    "f_dc": ["f_dc_0", "f_dc_1", "f_dc_2"],
    "f_rest": [f"f_rest_{i}" for i in range(45)],
}


def read_ply(path):
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        if "format binary_little_endian 1.0" not in header:
            sys.exit(f"{path}: not a binary little-endian .ply")
        count, names = 0, []
        for line in header:
            words = line.split()
            if words[:2] == ["element", "vertex"]:
                count = int(words[2])
            elif words[:1] == ["property"]:
                if words[1] != "float":
                    sys.exit(f"{path}: property '{line}' is not a float")
                names.append(words[2])
        data = np.frombuffer(f.read(4 * count * len(names)), dtype="<f4")
    if data.size != count * len(names):
        sys.exit(f"{path}: truncated ({data.size} of {count * len(names)} values)")
    return header, names, data.reshape(count, len(names)).copy()


def write_ply(path, header, data):
    with open(path + ".tmp", "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.astype("<f4").tobytes())
    os.replace(path + ".tmp", path)


def nearest(queries, points, chunk=512):
    """Index of each query's nearest point (exact, brute force in chunks)."""
    pn = (points * points).sum(1)
    out = np.empty(len(queries), dtype=np.int64)
    for s in range(0, len(queries), chunk):
        q = queries[s:s + chunk]
        d = pn[None, :] - 2.0 * q @ points.T
        out[s:s + chunk] = d.argmin(1)
    return out


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    _, written_names, written = read_ply(sys.argv[1])
    header, back_names, back = read_ply(sys.argv[2])
    if len(written) != len(back):
        print(f"Gaussian counts differ: written {len(written)}, back {len(back)}")
    col = lambda names, n: names.index(n)
    pos_w = written[:, [col(written_names, n) for n in GROUPS["position"]]].astype(np.float64)
    pos_b = back[:, [col(back_names, n) for n in GROUPS["position"]]].astype(np.float64)
    match = nearest(pos_b, pos_w)
    print(f"matched by position: {len(np.unique(match))} distinct of {len(back)}")
    os.makedirs(sys.argv[3], exist_ok=True)
    for group, names in GROUPS.items():
        names = [n for n in names if n in written_names and n in back_names]
        if not names:
            continue
        wi = [col(written_names, n) for n in names]
        bi = [col(back_names, n) for n in names]
        b, w = back[:, bi].astype(np.float64), written[match][:, wi].astype(np.float64)
        if group == "rotation":  # unit quaternions; q and -q are the same rotation
            b /= np.linalg.norm(b, axis=1, keepdims=True)
            w /= np.linalg.norm(w, axis=1, keepdims=True)
            b *= np.where((b * w).sum(1, keepdims=True) < 0, -1.0, 1.0)
        diff = b - w
        rms = float(np.sqrt((diff**2).mean()))
        p99 = float(np.quantile(np.abs(diff), 0.99))
        ref = float(np.sqrt((written[:, wi].astype(np.float64)**2).mean()))
        print(f"{group:9s} error RMS {rms:.5f}, p99 |e| {p99:.5f} (values RMS {ref:.5f})")
        fixed = back.copy()
        fixed[:, bi] = written[match][:, wi]
        write_ply(os.path.join(sys.argv[3], f"fix_{group}.ply"), header, fixed)


if __name__ == "__main__":
    main()
