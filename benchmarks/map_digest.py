"""A map's content digest (`lmjx.mapfile.digest`): SHA-256 over every dataset of its content
(name, dtype, shape, bytes), leaving out the attributes and the push counts (derived from the
edges).  Two builds with the same command and seed are the same map when their digests agree;
an evaluation records the digests of the maps it ran on (docs/evaluation/README.md lists the
present runs').  The digest is always computed here, and compared with the one the build
stored in the map (`content_digest`) where there is one.

    python benchmarks/map_digest.py [-v] maps/case1.h5 maps/case2.h5     (-v: each dataset's too)
"""

from __future__ import annotations

import sys

from lmjx.mapfile.digest import content_digest, stored_digest

if __name__ == "__main__":
    verbose = "-v" in sys.argv[1:]
    paths = [a for a in sys.argv[1:] if a != "-v"]
    if not paths:
        sys.exit(__doc__.split("\n\n")[-1].strip())
    mismatch = False
    for p in paths:
        each: dict[str, str] = {}
        d, n = content_digest(p, each)
        stored = stored_digest(p)
        note = "" if stored is None else ", as stored" if stored == d else f", NOT the stored {stored}"
        mismatch |= stored is not None and stored != d
        print(f"{d}  {p}  ({n} datasets{note})", flush=True)
        if verbose:
            print("\n".join(f"  {v}  {k}" for k, v in each.items()), flush=True)
    sys.exit(1 if mismatch else 0)
