"""Hand-made IGES text for the cadbridge.iges tests (formatting only; no geometry logic).

`make_iges` lays out entities given as raw parameter strings into S/G/D/P/T records, so a
test states exactly which fields a file holds and computes expected values by hand.
"""

from __future__ import annotations

DEFAULT_GLOBAL = ("1H,,1H;,4Htest,8Htest.igs,8Hhandmade,3H1.0,32,38,6,308,15,4Htest,1.,2,2HMM,1,1.,"
                  "15H20240101.000000,1E-6,100.,6Hauthor,3Horg,11,0,15H20240101.000000;")


def _pack(text: str, width: int, delims: str = ",;") -> list[str]:
    """Split ``text`` into lines of at most ``width`` characters, breaking after a delimiter."""
    out, cur = [], ""
    i = 0
    pieces = []
    tok = ""
    for ch in text:
        tok += ch
        if ch in delims:
            pieces.append(tok)
            tok = ""
    if tok:
        pieces.append(tok)
    for pc in pieces:
        if len(cur) + len(pc) > width and cur:
            out.append(cur)
            cur = ""
        while len(pc) > width:
            out.append(pc[:width])
            pc = pc[width:]
        cur += pc
    if cur:
        out.append(cur)
    return out


def make_iges(entities: list[dict], global_text: str = DEFAULT_GLOBAL, start: str = "test file",
              pdelims: str = ",;") -> str:
    """IGES text for ``entities``: dicts with ``params`` (the full parameter record, e.g.
    ``"110,0.,0.,0.,1.,0.,0.;"``) and optional ``form``, ``transform`` (DE number),
    ``status`` (8 digits), ``color``, ``label``, ``subscript``, ``level``. Entity k gets DE 2k+1."""
    s_lines = [start.ljust(72) + f"S{1:7d}"]
    g_lines = [g.ljust(72) + f"G{k + 1:7d}" for k, g in enumerate(_pack(global_text, 72, pdelims))]
    d_lines, p_lines = [], []
    for k, e in enumerate(entities):
        de = 2 * k + 1
        etype = int(e["params"].split(pdelims[0])[0])
        body = _pack(e["params"], 64, pdelims)
        ptr = len(p_lines) + 1
        for b in body:
            p_lines.append(b.ljust(64) + f" {de:7d}P{len(p_lines) + 1:7d}")
        d1 = (f"{etype:8d}{ptr:8d}{0:8d}{0:8d}{e.get('level', 0):8d}{0:8d}{e.get('transform', 0):8d}{0:8d}"
              f"{e.get('status', '00000000'):>8s}")
        d2 = (f"{etype:8d}{0:8d}{e.get('color', 0):8d}{len(body):8d}{e.get('form', 0):8d}{'':8s}{'':8s}"
              f"{e.get('label', ''):>8s}{e.get('subscript', 0):8d}")
        d_lines.append(d1 + f"D{len(d_lines) + 1:7d}")
        d_lines.append(d2 + f"D{len(d_lines) + 1:7d}")
    t = f"S{len(s_lines):7d}G{len(g_lines):7d}D{len(d_lines):7d}P{len(p_lines):7d}".ljust(72) + f"T{1:7d}"
    return "\n".join(s_lines + g_lines + d_lines + p_lines + [t]) + "\n"


def bilinear_128(corners=((0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)), domain=(0.0, 1.0, 0.0, 1.0)) -> str:
    """A 128 record for the bilinear patch with corners P00, P10, P01, P11 (degree 1x1)."""
    u0, u1, v0, v1 = domain
    pts = ",".join(f"{float(c)!r}" for p in corners for c in p)
    return (f"128,1,1,1,1,0,0,1,0,0,{u0!r},{u0!r},{u1!r},{u1!r},{v0!r},{v0!r},{v1!r},{v1!r},"
            f"1.,1.,1.,1.,{pts},{u0!r},{u1!r},{v0!r},{v1!r};")


# Appendix A of Neto (2010): a single 128 surface written by GiD. Re-typed from the thesis
# text (the PDF extraction broke some numbers across columns); the parameter values are the
# thesis's, laid out in 80-column records.
THESIS_APPENDIX_A = """\
Translator GID - IGES                                                   S0000001
1H,,1H;,3HGID,19HC:/CEMMUC/FA/60.igs,3HGID,3H1.0,32,38,6,308,15,5HCIMNE G0000001
,1.,2,2HMM,1,1.,13H100101.120000,0.001,10.,5HCIMNE,5HCIMNE,9,0,;        G0000002
     128       1       0       1       0       0       0       000000001D0000001
     128       0       0       9       0                NURBSURF       1D0000002
128,7,1,3,1,0,0,1,0,0,0,0,0,0,0.2696129,0.50025292,0.69102833,         1P0000001
0.81038681,1,1,1,1,0,0,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,            1P0000002
-2.804053,-5.16892,0,-3.0315653,-4.0968669,0,-3.0830998,               1P0000003
-2.6158131,0,-2.450814,-0.24658376,0,-1.5993302,1.3546726,0,           1P0000004
-1.2423752,3.0707054,0,-1.1892867,3.9613801,0,-1.250001,               1P0000005
4.729729,0,-2.804053,-5.16892,10,-3.0315653,-4.0968669,10,             1P0000006
-3.0830998,-2.6158131,10,-2.450814,-0.24658376,10,-1.5993302,          1P0000007
1.3546726,10,-1.2423752,3.0707054,10,-1.1892867,3.9613801,10,          1P0000008
-1.250001,4.729729,10,0,1,0,1;                                         1P0000009
S0000001G0000002D0000002P0000009                                        T0000001
"""

THESIS_XY = [(-2.804053, -5.16892), (-3.0315653, -4.0968669), (-3.0830998, -2.6158131),
             (-2.450814, -0.24658376), (-1.5993302, 1.3546726), (-1.2423752, 3.0707054),
             (-1.1892867, 3.9613801), (-1.250001, 4.729729)]
THESIS_KNOTS_S = [0, 0, 0, 0, 0.2696129, 0.50025292, 0.69102833, 0.81038681, 1, 1, 1, 1]
