#!/usr/bin/env python3
"""Reads PLY vertex properties with the standard library only (an independent reader of what
`pbgi` writes) and checks one property of them for tests/tools/cli_test.sh. Exit 0: holds.
  ply_check.py count FILE N                   N vertices
  ply_check.py props FILE NAME...             these vertex properties exist
  ply_check.py radius FILE LO HI              median radius in [LO, HI]
  ply_check.py mean FILE NAME LO HI           mean of property NAME in [LO, HI]
  ply_check.py normals FILE REF MIN FRACTION  at least FRACTION of FILE's points, matched to REF's
                                              by position, have |dot(n, n_ref)| >= MIN
  ply_check.py differ FILE A B                properties A and B differ somewhere
  ply_check.py big_endian IN OUT              rewrites a binary PLY as big-endian (the test
                                              writes one: no tool at hand writes them)
"""
import struct
import sys

TYPES = {"char": "b", "int8": "b", "uchar": "B", "uint8": "B", "short": "h", "int16": "h",
         "ushort": "H", "uint16": "H", "int": "i", "int32": "i", "uint": "I", "uint32": "I",
         "float": "f", "float32": "f", "double": "d", "float64": "d"}


def read(path):
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header") + len(b"end_header")
    while data[end:end + 1] in (b"\r", b"\n"):
        end += 1
        if data[end - 1:end] == b"\n":
            break
    fmt, count, props, in_vertex = "ascii", 0, [], False
    for line in data[:end].decode("latin-1").splitlines():
        w = line.split()
        if not w:
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            in_vertex = w[1] == "vertex"
            if in_vertex:
                count = int(w[2])
        elif w[0] == "property" and in_vertex:
            props.append((w[-1], TYPES[w[1]]))
    names = [p[0] for p in props]
    if fmt == "ascii":
        rows = data[end:].decode("latin-1").split("\n")[:count]
        values = [[float(v) for v in r.split()[:len(props)]] for r in rows]
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        rec = struct.Struct(order + "".join(p[1] for p in props))
        values = [list(rec.unpack_from(data, end + i * rec.size)) for i in range(count)]
    return names, values


def column(names, values, name):
    k = names.index(name)
    return [v[k] for v in values]


def main(argv):
    what, path = argv[1], argv[2]
    names, values = read(path)
    if what == "count":
        return len(values) == int(argv[3])
    if what == "props":
        missing = [n for n in argv[3:] if n not in names]
        if missing:
            print(f"{path} lacks {missing}; has {names}")
        return not missing
    if what == "radius":
        r = sorted(column(names, values, "radius"))
        med = r[len(r) // 2]
        print(f"median radius {med:.4g}")
        return float(argv[3]) <= med <= float(argv[4])
    if what == "mean":
        c = column(names, values, argv[3])
        mean = sum(c) / max(1, len(c))
        print(f"mean {argv[3]} {mean:.4g}")
        return float(argv[4]) <= mean <= float(argv[5])
    if what == "big_endian":
        with open(path, "rb") as f:
            data = f.read()
        end = data.index(b"end_header\n") + len(b"end_header\n")
        types = [TYPES[w.split()[1]] for w in data[:end].decode("latin-1").splitlines()
                 if w.startswith("property ")]
        rec_in, rec_out = struct.Struct("<" + "".join(types)), struct.Struct(">" + "".join(types))
        head = data[:end].replace(b"binary_little_endian", b"binary_big_endian")
        body = b"".join(rec_out.pack(*v) for v in values)
        with open(argv[3], "wb") as f:
            f.write(head + body)
        return rec_in.size * len(values) == len(data) - end
    if what == "differ":
        return column(names, values, argv[3]) != column(names, values, argv[4])
    if what == "normals":
        rnames, rvalues = read(argv[3])
        # A store keeps positions on a grid of 2^21 cells per axis (docs/format.md, format
        # version 3): match each point with the nearest reference point within 1e-4.
        pos = lambda v, n: [v[n.index(c)] for c in ("x", "y", "z")]
        key = lambda p: tuple(round(a * 1e4) for a in p)
        ref = {}
        for v in rvalues:
            p = pos(v, rnames)
            ref.setdefault(key(p), []).append((p, [v[rnames.index(c)] for c in ("nx", "ny", "nz")]))

        def nearest(p):
            kx, ky, kz = key(p)
            best, best_d = None, 1e-8
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    for dz in (-1, 0, 1):
                        for q, nrm in ref.get((kx + dx, ky + dy, kz + dz), ()):
                            d = sum((a - b) ** 2 for a, b in zip(p, q))
                            if d <= best_d:
                                best, best_d = nrm, d
            return best

        good = matched = 0
        for v in values:
            m = nearest(pos(v, names))
            if m is None:
                continue
            matched += 1
            n = [v[names.index(c)] for c in ("nx", "ny", "nz")]
            length = (sum(a * a for a in n) * sum(b * b for b in m)) ** 0.5
            good += length > 0 and abs(sum(a * b for a, b in zip(n, m))) / length >= float(argv[4])
        print(f"{good} of {matched} matched points ({len(values)} in all) agree")
        return matched == len(values) and good >= float(argv[5]) * matched
    raise SystemExit(f"unknown check {what}")


if __name__ == "__main__":
    sys.exit(0 if main(sys.argv) else 1)
