#!/usr/bin/env python3
"""Known-answer vectors for src/rng.rs from an independent implementation (standard library only).

Implements, from the published descriptions and not from the Rust code: SplitMix64 seeding, xoshiro256++
(Blackman & Vigna), the derived draws of `Rng` (uniform, uniform_range, below, normal, fill_normal_f32,
fork) and `unit_seed`'s construction (the first 8 bytes, little-endian, of BLAKE3 over a fixed byte
layout). BLAKE3 is implemented here for one chunk (inputs up to 1024 bytes, enough for unit seeds).

Before printing anything the script checks itself against published values:
  - xoshiro256++ from the state [1, 2, 3, 4]: the ten outputs the authors' reference C code gives (as
    quoted by the rand_xoshiro crate's tests);
  - SplitMix64 from 0: its first output 0xE220A8397B1DCDAF (the reference splitmix64.c);
  - BLAKE3 of 0, 1 and 1023 bytes of the official test-vector input (bytes i mod 251), from the BLAKE3
    team's test_vectors.json; and, if the `blake3` package is importable, random inputs against it.

Usage: python3 tests/python/rng_vectors.py    (prints the Rust constants pasted into src/rng.rs's tests)
"""
import math
import struct
import sys

M64 = (1 << 64) - 1


def rotl64(x, k):
    return ((x << k) | (x >> (64 - k))) & M64


def splitmix64(state):
    """Returns (next state, output)."""
    state = (state + 0x9E3779B97F4A7C15) & M64
    z = state
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
    return state, z ^ (z >> 31)


class Xoshiro256pp:
    def __init__(self, seed=None, state=None):
        if state is None:
            state, x = [], seed
            for _ in range(4):
                x, out = splitmix64(x)
                state.append(out)
        self.s = list(state)

    def next_u64(self):
        s = self.s
        result = (rotl64((s[0] + s[3]) & M64, 23) + s[0]) & M64
        t = (s[1] << 17) & M64
        s[2] ^= s[0]
        s[3] ^= s[1]
        s[1] ^= s[2]
        s[0] ^= s[3]
        s[2] ^= t
        s[3] = rotl64(s[3], 45)
        return result

    def uniform(self):
        return (self.next_u64() >> 11) * 2.0**-53

    def uniform_range(self, lo, hi):
        return lo + (hi - lo) * self.uniform()

    def below(self, n):
        return (self.next_u64() * n) >> 64

    def normal(self):
        u1 = 1.0 - self.uniform()
        u2 = self.uniform()
        return math.sqrt(-2.0 * math.log(u1)) * math.cos(math.tau * u2)

    def fill_normal_f32(self, n):
        out = []
        while len(out) < n:
            u1 = 1.0 - self.uniform()
            u2 = self.uniform()
            r = math.sqrt(-2.0 * math.log(u1))
            out.append(f32(r * math.cos(math.tau * u2)))
            if len(out) < n:
                out.append(f32(r * math.sin(math.tau * u2)))
        return out

    def fork(self, stream):
        s = self.s
        return Xoshiro256pp(seed=s[0] ^ ((stream * 0xD6E8FEB86659FD93) & M64) ^ rotl64(s[2], 17))


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


# ---- BLAKE3, one chunk (the specification's compression function and chunk chaining) ----

B3_IV = [0x6A09E667, 0xBB67AE85, 0x3C6EF372, 0xA54FF53A, 0x510E527F, 0x9B05688C, 0x1F83D9AB, 0x5BE0CD19]
B3_PERM = [2, 6, 3, 10, 7, 0, 4, 13, 1, 11, 12, 5, 9, 14, 15, 8]
CHUNK_START, CHUNK_END, ROOT = 1, 2, 8
M32 = 0xFFFFFFFF


def rotr32(x, k):
    return ((x >> k) | (x << (32 - k))) & M32


def b3_g(v, a, b, c, d, mx, my):
    v[a] = (v[a] + v[b] + mx) & M32
    v[d] = rotr32(v[d] ^ v[a], 16)
    v[c] = (v[c] + v[d]) & M32
    v[b] = rotr32(v[b] ^ v[c], 12)
    v[a] = (v[a] + v[b] + my) & M32
    v[d] = rotr32(v[d] ^ v[a], 8)
    v[c] = (v[c] + v[d]) & M32
    v[b] = rotr32(v[b] ^ v[c], 7)


def b3_compress(cv, block, counter, block_len, flags):
    m = list(struct.unpack("<16I", block))
    v = list(cv) + B3_IV[:4] + [counter & M32, (counter >> 32) & M32, block_len, flags]
    for rnd in range(7):
        b3_g(v, 0, 4, 8, 12, m[0], m[1])
        b3_g(v, 1, 5, 9, 13, m[2], m[3])
        b3_g(v, 2, 6, 10, 14, m[4], m[5])
        b3_g(v, 3, 7, 11, 15, m[6], m[7])
        b3_g(v, 0, 5, 10, 15, m[8], m[9])
        b3_g(v, 1, 6, 11, 12, m[10], m[11])
        b3_g(v, 2, 7, 8, 13, m[12], m[13])
        b3_g(v, 3, 4, 9, 14, m[14], m[15])
        if rnd < 6:
            m = [m[i] for i in B3_PERM]
    return [v[i] ^ v[i + 8] for i in range(8)] + [v[i + 8] ^ cv[i] for i in range(8)]


def blake3_32(data):
    """The default 32-byte BLAKE3 hash of `data` (at most one 1024-byte chunk)."""
    assert len(data) <= 1024, "this BLAKE3 handles one chunk only"
    blocks = [data[i:i + 64] for i in range(0, len(data), 64)] or [b""]
    cv = B3_IV
    for i, blk in enumerate(blocks):
        flags = (CHUNK_START if i == 0 else 0) | (CHUNK_END | ROOT if i == len(blocks) - 1 else 0)
        out = b3_compress(cv, blk.ljust(64, b"\0"), 0, len(blk), flags)
        cv = out[:8]
    return struct.pack("<8I", *cv)


def unit_seed(build_seed, frame_key, sample_index):
    key = frame_key.encode()
    data = b"pointreggpt-unit-seed-v1" + struct.pack("<QQ", build_seed, len(key)) + key + struct.pack("<Q", sample_index)
    return struct.unpack("<Q", blake3_32(data)[:8])[0]


def self_check():
    r = Xoshiro256pp(state=[1, 2, 3, 4])
    reference = [41943041, 58720359, 3588806011781223, 3591011842654386, 9228616714210784205, 9973669472204895162,
                 14011001112246962877, 12406186145184390807, 15849039046786891736, 10450023813501588000]
    assert [r.next_u64() for _ in reference] == reference, "xoshiro256++ differs from the reference C code"
    assert splitmix64(0)[1] == 0xE220A8397B1DCDAF, "SplitMix64 differs from splitmix64.c"
    official = {
        0: "af1349b9f5f9a1a6a0404dea36dcc9499bcb25c9adc112b7cc9a93cae41f3262",
        1: "2d3adedff11b61f14c886e35afa036736dcd87a74d27b5c1510225d0f592e213",
        1023: "10108970eeda3eb932baac1428c7a2163b0e924c9a9e25b35bba72b28f70bd11",
    }
    for n, want in official.items():
        assert blake3_32(bytes(i % 251 for i in range(n))).hex() == want, f"BLAKE3 of {n} bytes differs from the official vector"
    try:
        import blake3  # optional second opinion
    except ImportError:
        return "blake3 package not installed: BLAKE3 checked against the official vectors only"
    g = Xoshiro256pp(seed=99)
    for _ in range(200):
        data = bytes(g.below(256) for _ in range(g.below(1025)))
        assert blake3_32(data) == blake3.blake3(data).digest(), "BLAKE3 differs from the blake3 package"
    return "BLAKE3 also agrees with the blake3 package on 200 random inputs"


def hex64(v):
    return f"0x{v:016X}"


def main():
    note = self_check()
    print(f"// self-check passed ({note})")
    seeds = [0, 1, 42, 0xDEADBEEF, M64]
    print("const NEXT_U64: [(u64, [u64; 4]); 5] = [")
    for s in seeds:
        r = Xoshiro256pp(seed=s)
        print(f"    ({hex64(s)}, [{', '.join(hex64(r.next_u64()) for _ in range(4))}]),")
    print("];")
    r = Xoshiro256pp(seed=7)
    print(f"const UNIFORM_SEED_7: [f64; 4] = [{', '.join(repr(r.uniform()) for _ in range(4))}];")
    r = Xoshiro256pp(seed=7)
    print(f"const UNIFORM_RANGE_SEED_7: [f64; 2] = [{repr(r.uniform_range(-2.5, 4.0))}, {repr(r.uniform_range(0.6, 4.0))}];")
    r = Xoshiro256pp(seed=8)
    print(f"const BELOW_SEED_8: [u64; 4] = [{', '.join(str(r.below(n)) for n in (1, 10, 1000, M64))}];")
    r = Xoshiro256pp(seed=9)
    print(f"const NORMAL_SEED_9: [f64; 4] = [{', '.join(repr(r.normal()) for _ in range(4))}];")
    r = Xoshiro256pp(seed=10)
    print(f"const FILL_NORMAL_F32_SEED_10: [f32; 5] = [{', '.join(repr(v) for v in r.fill_normal_f32(5))}];")
    # fork of a fresh generator, fork after three draws, and the synthetic source's noise-seed chain.
    r = Xoshiro256pp(seed=11)
    a = r.fork(0).next_u64()
    b = r.fork(5).next_u64()
    for _ in range(3):
        r.next_u64()
    c = r.fork(5).next_u64()
    d = Xoshiro256pp(seed=3).fork(0x5E45).fork(2).next_u64()
    print(f"const FORK: [u64; 4] = [{hex64(a)}, {hex64(b)}, {hex64(c)}, {hex64(d)}];")
    cases = [(0, "", 0), (1, "scene/frame-000000", 0), (11, "synthetic-0/frame-000005", 1), (M64, "7-scenes-redkitchen/seq-01/frame-000300", 3)]
    print("const UNIT_SEED: [(u64, &str, u64, u64); 4] = [")
    for bs, key, idx in cases:
        print(f"    ({hex64(bs)}, {key!r}, {idx}, {hex64(unit_seed(bs, key, idx))}),".replace("'", '"'))
    print("];")


if __name__ == "__main__":
    sys.exit(main())
