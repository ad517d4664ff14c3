"""Compiled one-pass scan of a Parameter Data section (numba): DE back pointers, field
boundaries and numbers of every entity whose record is *plain*, for the fast path of
`cadbridge.iges.parameters`.

The kernel never raises and never decides anything the Python reader would decide
differently: whatever it cannot take with certainty (an entity whose lines do not all carry
its DE, a record delimiter missing, a Hollerith ``H`` anywhere in the record, any byte that is
not printable ASCII, a number it cannot convert exactly) is only *flagged*, and the Python
path (which also produces every located error message) handles it as before.

Plain record (the conditions of ``parameters._read_params_bulk``, slightly stricter): every
P line of the entity carries the entity's DE (plain ASCII digits), the record delimiter lies
within those lines, no ``H``/``h`` before it, only printable ASCII (32-126), and the first
field is the entity type as a plain integer. Fields are split at the parameter delimiter and
stripped of blanks (for printable ASCII, ``str.strip`` strips exactly the blanks).

Numbers: a field matching the IGES real syntax ``[+-]?(\\d+\\.?\\d*|\\.\\d+)([EeDd][+-]?\\d+)?`` of at
most ``MAX_TOKEN`` characters is converted here when the result is exactly what Python's
``float`` gives: at most 18 significant digits forming an integer m <= 2**53 and a decimal
exponent e with |e| <= 22, so that m * 10**e (or m / 10**-e) is one correctly rounded IEEE
operation on exact operands (Clinger's fast path, as in CPython's own conversion). A mantissa
of more than 53 bits (OCC writes 17 significant digits) with -22 <= e <= 0 is converted by exact
integer long division by 5**-e, rounded half to even (`_div_pow5_pow2`). Other valid numbers are
marked for conversion by Python (``float``), in one batch.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["scan_parameters", "K_EMPTY", "K_INT", "K_REAL", "K_OTHER"]

K_EMPTY, K_INT, K_REAL, K_OTHER = 0, 1, 2, 3
_TWO53 = 9007199254740992


@njit(cache=True, nogil=True)
def _pow10(k):
    r = 1.0
    for _ in range(k):
        r *= 10.0  # exact up to 1e22
    return r


@njit(cache=True, nogil=True)
def _div_pow5_pow2(m, k):
    """m / 10**k correctly rounded (round half to even), for 0 < m < 2**63 and 0 <= k <= 22:
    m / 5**k by exact integer long division (5**22 < 2**52, so every remainder fits an int64)
    until the quotient has 55 bits, the remainder kept as a sticky bit; then rounded to 53
    bits and scaled by the exact power of two 2**-(k + bits appended)."""
    d = 1
    for _ in range(k):
        d *= 5
    q = m // d
    r = m - q * d
    shift = 0  # bits appended to the quotient
    while q < 36028797018963968:  # 2**55
        r <<= 1
        q <<= 1
        if r >= d:
            r -= d
            q |= 1
        shift += 1
    sticky = r != 0
    nb = 0  # bit length of q
    while (q >> nb) > 0:
        nb += 1
    drop = nb - 53
    low = q & ((1 << drop) - 1)
    q >>= drop
    half = 1 << (drop - 1)
    if low > half or (low == half and (sticky or (q & 1) == 1)):
        q += 1
    return math.ldexp(float(q), drop - shift - k)


@njit(cache=True, nogil=True)
def _number(body, s, e, max_token):
    """Classify and convert the field at body offsets [s, e) (stripped, printable ASCII).
    Returns (kind, float exact, int exact, int value, float value)."""
    if e == s:
        return 0, True, False, 0, 0.0
    if e - s > max_token:
        return 3, False, False, 0, 0.0
    i = s
    c = body[i]
    neg = False
    if c == 43 or c == 45:  # + -
        neg = c == 45
        i += 1
    # mantissa digits: first pass finds the syntax and the significant digit range
    n_int = 0
    n_frac = 0
    dot = False
    first_nz = -1  # index (in the digit sequence) of the first / last non-zero digit
    last_nz = -1
    nd = 0
    while i < e:
        c = body[i]
        if 48 <= c <= 57:
            if c != 48:
                if first_nz < 0:
                    first_nz = nd
                last_nz = nd
            nd += 1
            if dot:
                n_frac += 1
            else:
                n_int += 1
            i += 1
        elif c == 46 and not dot:
            dot = True
            i += 1
        else:
            break
    if n_int == 0 and n_frac == 0:
        return 3, False, False, 0, 0.0
    has_exp = False
    ex = 0
    if i < e:
        c = body[i]
        if not (c == 69 or c == 101 or c == 68 or c == 100):  # E e D d
            return 3, False, False, 0, 0.0
        has_exp = True
        i += 1
        eneg = False
        if i < e:
            c = body[i]
            if c == 43 or c == 45:
                eneg = c == 45
                i += 1
        n_exp = 0
        while i < e:
            c = body[i]
            if 48 <= c <= 57:
                if ex < 100000:
                    ex = ex * 10 + (c - 48)
                n_exp += 1
                i += 1
            else:
                return 3, False, False, 0, 0.0
        if n_exp == 0:
            return 3, False, False, 0, 0.0
        if eneg:
            ex = -ex
    kind = 1 if (not dot and not has_exp) else 2
    if first_nz < 0:  # all digits zero
        v = 0.0
        if neg:
            v = -v
        return kind, True, kind == 1, 0, v
    nsig = last_nz - first_nz + 1
    if nsig > 18:
        return kind, False, False, 0, 0.0
    # second pass: accumulate the significant digits
    m = 0
    j = 0
    i = s
    while i < e:
        c = body[i]
        if 48 <= c <= 57:
            if first_nz <= j <= last_nz:
                m = m * 10 + (c - 48)
            j += 1
        elif c != 46 and c != 43 and c != 45:
            break
        i += 1
    # value = m * 10 ** e10 (trailing zeros of the digit string moved into the exponent)
    e10 = ex - n_frac + (nd - 1 - last_nz)
    iv = 0
    iexact = False
    if kind == 1 and nsig + e10 <= 18:  # an integer field of at most 18 significant digits
        iv = m
        for _ in range(e10):
            iv *= 10
        if neg:
            iv = -iv
        iexact = True
    if m > _TWO53 and -22 <= e10 <= 0:  # 17-18 significant digits (OCC's %.17g): exact division
        v = _div_pow5_pow2(m, -e10)
        if neg:
            v = -v
        return kind, True, iexact, iv, v
    if m > _TWO53 or e10 > 22 or e10 < -22:
        return kind, False, iexact, iv, 0.0
    if e10 >= 0:
        v = float(m) * _pow10(e10)
    else:
        v = float(m) / _pow10(-e10)
    if neg:
        v = -v
    return kind, True, iexact, iv, v


@njit(cache=True, nogil=True)
def _scan(body, backf, n, ppos, pcnt, des, etypes, pdelim, rdelim, max_token):
    """body: columns 1-64 of the n records joined; backf: (n, 7) columns 66-72; per entity its first P line
    (0-based), line count, DE and type. Returns the per-record back pointers, the per-entity
    status/token ranges/last line and the per-token arrays."""
    # back pointers (columns 66-72): plain ASCII digits between blanks -> value; all blank
    # -> -1 (as Python's isdigit fails); anything else -> -3 (Python decides)
    back = np.empty(n, np.int64)
    for r in range(n):
        a = 0
        b = 7
        while a < b and backf[r, a] == 32:
            a += 1
        while b > a and backf[r, b - 1] == 32:
            b -= 1
        if a == b:
            back[r] = -1
            continue
        v = 0
        ok = True
        for q in range(a, b):
            c = backf[r, q]
            if 48 <= c <= 57:
                v = v * 10 + (c - 48)
            else:
                ok = False
                break
        back[r] = v if ok else -3
    ne = ppos.shape[0]
    status = np.zeros(ne, np.uint8)  # 1: plain (fast path), 0: Python path
    t_first = np.zeros(ne, np.int64)
    t_count = np.zeros(ne, np.int64)
    last_rec = np.zeros(ne, np.int64)
    all_ok = np.zeros(ne, np.uint8)
    # token capacity: one more than the delimiters of the section (each entity's last field)
    cap = ne
    for i in range(64 * n):
        if body[i] == pdelim:
            cap += 1
    tstart = np.empty(cap, np.int64)
    tend = np.empty(cap, np.int64)
    trec = np.empty(cap, np.int64)
    kind = np.empty(cap, np.uint8)
    exact = np.empty(cap, np.uint8)  # bit 0: fval exact, bit 1: ival exact (integer field)
    ival = np.empty(cap, np.int64)
    fval = np.empty(cap, np.float64)
    nt = 0
    for k in range(ne):
        a = ppos[k]
        if a < 0 or a >= n:
            continue
        de = des[k]
        b = a + max(pcnt[k], 1)
        if b > n:
            b = n
        good = True
        for r in range(a, b):
            if back[r] != de:
                good = False
                break
        if not good:
            continue
        while b < n and back[b] == de:
            b += 1
        if b < n and back[b] == -3:
            continue
        # record delimiter, and the byte checks, over columns 1-64 of lines a..b-1
        jr = -1
        for i in range(64 * a, 64 * b):
            c = body[i]
            if c == rdelim:
                jr = i
                break
            if c < 32 or c > 126 or c == 72 or c == 104:  # control / non-ASCII / H h
                good = False
                break
        if not good or jr < 0:
            continue
        if nt + (jr - 64 * a) + 1 > cap:  # cannot happen (capacity counts every delimiter)
            continue
        t0 = nt
        ps = 64 * a  # start of the raw part
        i = ps
        while True:
            # find the end of this part
            j = i
            while j < jr and body[j] != pdelim:
                j += 1
            s = i
            e = j
            while s < e and body[s] == 32:
                s += 1
            while e > s and body[e - 1] == 32:
                e -= 1
            tstart[nt] = s
            tend[nt] = e
            trec[nt] = ps // 64
            kd, fx, ix, iv, fv = _number(body, s, e, max_token)
            kind[nt] = kd
            exact[nt] = (1 if fx else 0) | (2 if ix else 0)
            ival[nt] = iv
            fval[nt] = fv
            nt += 1
            if j >= jr:
                break
            i = j + 1
            ps = i
        # the first field must be the entity type as a plain integer
        if not (kind[t0] == 1 and (exact[t0] & 2) != 0 and ival[t0] == etypes[k]):
            nt = t0
            continue
        okall = 1
        for q in range(t0, nt):
            if kind[q] == 3 or (exact[q] & 1) == 0:
                okall = 0
                break
        status[k] = 1
        t_first[k] = t0
        t_count[k] = nt - t0
        last_rec[k] = b - 1
        all_ok[k] = okall
    return (back, status, t_first, t_count, last_rec, all_ok, tstart[:nt], tend[:nt], trec[:nt], kind[:nt],
            exact[:nt], ival[:nt], fval[:nt])


def scan_parameters(raw: bytes, n: int, ppos, pcnt, des, etypes, pdelim: str, rdelim: str, max_token: int):
    """Run the kernel on the P section ``raw`` (n records of 72 bytes, columns 1-72)."""
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(n, 72)
    body = np.ascontiguousarray(rows[:, :64]).reshape(-1)
    backf = np.ascontiguousarray(rows[:, 65:72])
    return _scan(body, backf, n, np.asarray(ppos, np.int64), np.asarray(pcnt, np.int64), np.asarray(des, np.int64),
                 np.asarray(etypes, np.int64), ord(pdelim), ord(rdelim), max_token)
