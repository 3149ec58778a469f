//! `cargo xtask gen [--check]`: writes the straight-line covariance kernels of the seeker INS
//! (`nav-core/src/seeker_ins/generated/`) from the sparsity of its error model, known here at
//! build time. `--check` fails when the committed files differ from what the generator writes
//! (`cargo xtask ci` runs it).
//!
//! The prediction `P ← Φ P Φᵀ + Q_d` of the 17-state model (module doc of
//! `nav-core/src/seeker_ins/error_model.rs`): `G = F Δt` has 61 structurally non-zero entries
//! (52 in the prediction: [`NEGLIGIBLE`] lists the nine it leaves out),
//! all in rows 0..9 and columns {0, 2..15}; `Φ = I + A`, `A = G + H G` with `H = ½ G_f` the
//! nine second-order couplings (velocity → position, attitude → velocity). Rows 9..17 of Φ are
//! the identity (bias and gimbal states are random constants), so only rows and columns 0..9
//! of P change. The generated code reads the upper triangle of P only and computes
//!
//! ```text
//! W = G P                    rows 0..9, every column used below      (52 terms a column)
//! U = P + (W + H W)          = Φ P, rows 0..9
//! Y = U Gᵀ                   upper triangle of the 9×9 corner
//! P'[i,j] = U[i,j] + (Y[i,j] + Σ_m H[j,m] Y[i,m]) + Q_d[i,j]      i ≤ j < 9 (Φ P Φᵀ)
//! P'[i,j] = U[i,j]                                                 i < 9 ≤ j
//! ```
//!
//! and mirrors every written entry (P stays exactly symmetric). The terms of every sum are
//! emitted in a fixed order, so host and target compute the same bits.

use crate::root;
use std::fmt::Write as _;
use std::path::PathBuf;

/// Number of error states of the seeker INS.
const N: usize = 17;
/// Rows (and columns) of P the prediction changes.
const NAV: usize = 9;
/// First column of P whose column of U = Φ P the prediction computes in a loop (the columns
/// before it are written out: column 1 needs two rows of U only).
const LOOP_FROM: usize = 2;

/// One structurally non-zero entry of G = F Δt: row, column, the field of `SparseF` (scaled)
/// that holds it, and whether it enters with a minus sign.
struct Entry {
    row: usize,
    col: usize,
    field: String,
    negated: bool,
}

fn e(row: usize, col: usize, field: &str, negated: bool) -> Entry {
    Entry {
        row,
        col,
        field: field.to_string(),
        negated,
    }
}

/// The sparsity of G and where each entry lives in `SparseF` (error_model.rs).
fn g_entries() -> Vec<Entry> {
    let xyz = ["x", "y", "z"];
    let mut v = vec![
        e(0, 0, "f00", false),
        e(0, 2, "f02", false),
        e(0, 3, "f03", false),
        e(1, 0, "f10", false),
        e(1, 2, "f12", false),
        e(1, 4, "f14", false),
        e(2, 5, "f25", false),
    ];
    // Velocity rows: [vel_lat vel_h vel_vel [f×] C_b^n 0].
    for (r, axis) in xyz.iter().enumerate() {
        v.push(e(3 + r, 0, &format!("vel_lat.{axis}"), false));
        v.push(e(3 + r, 2, &format!("vel_h.{axis}"), false));
        for c in 0..3 {
            v.push(e(
                3 + r,
                3 + c,
                &format!("vel_vel.m{}{}", r + 1, c + 1),
                false,
            ));
        }
        for (c, field, neg) in skew_entries(r) {
            v.push(e(3 + r, 6 + c, &format!("f_ned.{field}"), neg));
        }
        for c in 0..3 {
            v.push(e(
                3 + r,
                9 + c,
                &format!("c_b_n.m{}{}", r + 1, c + 1),
                false,
            ));
        }
    }
    // Attitude rows: [att_lat att_h W_v −[w_in×] 0 −C_b^n].
    let att_v = [(6, 4, "x"), (7, 3, "y"), (8, 4, "z")];
    for (r, (axis, (row, col, f))) in xyz.iter().zip(att_v).enumerate() {
        v.push(e(6 + r, 0, &format!("att_lat.{axis}"), false));
        v.push(e(6 + r, 2, &format!("att_h.{axis}"), false));
        v.push(e(row, col, &format!("att_v.{f}"), false));
        for (c, field, neg) in skew_entries(r) {
            v.push(e(6 + r, 6 + c, &format!("w_in.{field}"), !neg));
        }
        for c in 0..3 {
            v.push(e(
                6 + r,
                12 + c,
                &format!("c_b_n.m{}{}", r + 1, c + 1),
                true,
            ));
        }
    }
    v.retain(|x| !NEGLIGIBLE.contains(&(x.row, x.col)));
    v.sort_by_key(|x| (x.row, x.col));
    v
}

/// Entries of F the prediction leaves out (row, column; `SparseF` holds them as zero): those
/// of the height column through the transport rate and the radii, and ∂L̇/∂L with its
/// attitude counterpart. Largest |F| over |L| ≤ 80°, h −0.5…20 km, |V_N|, |V_E| ≤ 600 m/s,
/// |V_D| ≤ 100 m/s: δL̇/δh 1.5e-11, δl̇/δh 8.4e-11 (1/(m s)); δV̇_N/δh, δV̇_E/δh 5.1e-8
/// (1/s²); δφ̇_N/δh, δφ̇_E/δh 1.5e-11, δφ̇_D/δh 8.3e-11 (rad/(m s)); δL̇/δL and δφ̇_E/δL
/// 9.5e-7 (1/s, rad/(rad s)).
const NEGLIGIBLE: [(usize, usize); 9] = [
    (0, 0),
    (0, 2),
    (1, 2),
    (3, 2),
    (4, 2),
    (6, 2),
    (7, 0),
    (7, 2),
    (8, 2),
];

/// Row `r` of `[v×]`: (column, component, negated) of its two non-zero entries.
fn skew_entries(r: usize) -> [(usize, &'static str, bool); 2] {
    match r {
        0 => [(1, "z", true), (2, "y", false)],
        1 => [(0, "z", false), (2, "x", true)],
        _ => [(0, "y", true), (1, "x", false)],
    }
}

/// The second-order couplings `H = ½ G_f`: (row, column, local name of the halved entry,
/// negated).
fn h_entries() -> Vec<(usize, usize, &'static str, bool)> {
    vec![
        (0, 3, "h0_3", false),
        (1, 4, "h1_4", false),
        (2, 5, "h2_5", false),
        (3, 7, "hf_z", true),
        (3, 8, "hf_y", false),
        (4, 6, "hf_z", false),
        (4, 8, "hf_x", true),
        (5, 6, "hf_y", true),
        (5, 7, "hf_x", false),
    ]
}

/// A signed sum `t0 ± t1 ± …` of products (`a * b`) or plain values, left to right.
fn sum(terms: &[(String, bool)]) -> String {
    let mut s = String::new();
    for (i, (t, neg)) in terms.iter().enumerate() {
        match (i, neg) {
            (0, false) => s.push_str(t),
            (0, true) => {
                let _ = write!(s, "-({t})");
            }
            (_, false) => {
                let _ = write!(s, " + {t}");
            }
            (_, true) => {
                let _ = write!(s, " - {t}");
            }
        }
    }
    if s.is_empty() {
        s.push('z');
    }
    s
}

/// `(sum)` when it has more than one term, else the term.
fn paren(terms: &[(String, bool)]) -> String {
    if terms.len() > 1 {
        format!("({})", sum(terms))
    } else {
        sum(terms)
    }
}

/// Local name of the G entry at (row, col).
fn gname(r: usize, c: usize) -> String {
    format!("g{r}_{c}")
}

/// `U[i][j]` (rows 0..9 of Φ P) in the prediction kernel: a local of a written-out column, or an
/// element of the looped columns' array.
fn uref(j: usize, i: usize) -> String {
    if j < LOOP_FROM {
        format!("u{j}_{i}")
    } else {
        format!("ul[{}][{i}]", j - LOOP_FROM)
    }
}

/// P[i, j] read from the upper triangle of the column-major storage `p[col][row]`.
fn p_upper(i: usize, j: usize) -> String {
    let (r, c) = if i <= j { (i, j) } else { (j, i) };
    format!("p[{c}][{r}]")
}

const HEADER: &str = "// generated by cargo xtask gen; do not edit\n";

/// The prediction kernel source.
fn predict_source() -> String {
    let g = g_entries();
    let h = h_entries();
    let g_row = |r: usize| g.iter().filter(move |x| x.row == r);
    let g_cols: Vec<usize> = {
        let mut c: Vec<usize> = g.iter().map(|x| x.col).collect();
        c.sort_unstable();
        c.dedup();
        c
    };
    let mut s = String::from(HEADER);
    s.push_str(
        "//! `P ← Φ P Φᵀ + Q_d` of the 17-state seeker INS written out term by term from the\n\
         //! sparsity of `G = F Δt` (52 of its 61 entries;\n\
         //! the nine of `NEGLIGIBLE` in the generator left out) and of the second-order couplings `H = ½ G_f` (9\n\
         //! entries): `W = G P`, `U = P + (W + H W)` (rows 0..9 of Φ P), `Y = U Gᵀ` (upper\n\
         //! triangle), `P'[i,j] = U[i,j] + (Y[i,j] + Σ H[j,m] Y[i,m]) + Q_d[i,j]`. The columns\n\
         //! of U share one body, so all but the first two are computed in a loop (half the\n\
         //! flash of writing each out, about 18 instructions more per column). Generator:\n\
         //! `xtask/src/gen.rs`.\n\n",
    );
    s.push_str(
        "use super::super::sparse_f::SparseF;\nuse crate::Real;\n\n\
         /// `P ← Φ P Φᵀ + Q_d` in place for F = `f` and Δt = `dt` (s; G = F Δt entry by entry,\n\
         /// as `SparseF::scaled`), `p` exactly symmetric (column-major storage, `p[col][row]`;\n\
         /// the upper triangle of columns 0 and 1 is read, then whole columns: U = Φ P is one\n\
         /// loop body over the columns from 2 on), writing both triangles of rows and columns\n\
         /// 0..9. `qa`, `qg`: ½Δt times the accelerometer and gyro white-noise\n\
         /// PSDs ((m/s²)²/Hz, (rad/s)²/Hz); `qa2`, `qg2`: Δt times them (the variances added on\n\
         /// the velocity and attitude diagonals). `false` (and `p` unchanged) when a result is\n\
         /// not finite (a non-finite entry of G reaches every column of P'[0..9, 9..17]).\n\
         #[allow(clippy::too_many_arguments, clippy::too_many_lines, clippy::similar_names)]\n\
         #[inline(never)]\n\
         pub(in crate::seeker_ins) fn propagate_in_place<T: Real>(\n\
         \x20   p: &mut [[T; 17]; 17],\n\
         \x20   f: &SparseF<T>,\n\
         \x20   dt: T,\n\
         \x20   qa: T,\n\
         \x20   qg: T,\n\
         \x20   qa2: T,\n\
         \x20   qg2: T,\n\
         ) -> bool {\n\
         \x20   let z = T::zero();\n\
         \x20   let half = T::lit(0.5);\n",
    );
    for x in &g {
        let _ = writeln!(s, "    let {} = f.{} * dt;", gname(x.row, x.col), x.field);
    }
    s.push_str(
        "    let h0_3 = half * g0_3;\n    let h1_4 = half * g1_4;\n    let h2_5 = half * g2_5;\n\
         \x20   let hf_x = half * (f.f_ned.x * dt);\n    let hf_y = half * (f.f_ned.y * dt);\n\
         \x20   let hf_z = half * (f.f_ned.z * dt);\n",
    );
    // Liveness: U[i][1] is only read as P'[i][1] (column 1 of G is zero).
    let needed_u = |i: usize, j: usize| -> bool { j != 1 || i <= 1 };
    // Columns 0 and 1 written out (column 1 needs two rows only; `u{j}_{i}` = U[i][j]);
    // columns LOOP_FROM.. built by one body over the columns of P (`ul[j − LOOP_FROM][i]`;
    // whole columns of the exactly symmetric P), each element written once (no zeroed copy).
    for j in 0..N {
        if j == LOOP_FROM {
            let _ = writeln!(
                s,
                "    // Columns {LOOP_FROM}..{N}: one body, looped (P exactly symmetric: whole columns);\n\
                 \x20   // the columns from {NAV} on are results (probed below).\n\
                 \x20   let ul: [[T; 9]; {}] = core::array::from_fn(|k| {{\n\
                 \x20       let Some(col) = p.get(k + {LOOP_FROM}) else {{\n\
                 \x20           return [z; 9];\n\
                 \x20       }};",
                N - LOOP_FROM
            );
        }
        if j > LOOP_FROM {
            break;
        }
        let looped = j == LOOP_FROM;
        let ind = if looped { "        " } else { "    " };
        let read = |i: usize| {
            if looped {
                format!("col[{i}]")
            } else {
                p_upper(i, j)
            }
        };
        let write = |i: usize| {
            if looped {
                format!("u{i}")
            } else {
                uref(j, i)
            }
        };
        if !looped {
            let _ = writeln!(s, "    // Column {j}.");
        }
        let rows_needed: Vec<usize> = (0..NAV).filter(|&i| needed_u(i, j)).collect();
        // W rows needed: the rows themselves and the rows H reads.
        let mut w_rows: Vec<usize> = rows_needed.clone();
        for &(r, m, _, _) in &h {
            if rows_needed.contains(&r) {
                w_rows.push(m);
            }
        }
        w_rows.sort_unstable();
        w_rows.dedup();
        for &k in g_cols.iter() {
            let used = w_rows.iter().any(|&r| g_row(r).any(|x| x.col == k));
            if used {
                let _ = writeln!(s, "{ind}let x{k} = {};", read(k));
            }
        }
        for &r in &w_rows {
            let terms: Vec<(String, bool)> = g_row(r)
                .map(|x| (format!("{} * x{}", gname(x.row, x.col), x.col), x.negated))
                .collect();
            let _ = writeln!(s, "{ind}let w{r} = {};", sum(&terms));
        }
        for &i in &rows_needed {
            let mut terms = vec![(format!("w{i}"), false)];
            for &(r, m, name, neg) in &h {
                if r == i {
                    terms.push((format!("{name} * w{m}"), neg));
                }
            }
            let _ = writeln!(
                s,
                "{ind}let {} = {} + {};",
                write(i),
                read(i),
                paren(&terms)
            );
        }
        if looped {
            let all: Vec<String> = (0..NAV).map(|i| format!("u{i}")).collect();
            let _ = writeln!(s, "        [{}]\n    }});", all.join(", "));
        }
    }
    // Row by row of U (rows 0..9): Y[i][m] = Σ_k U[i][k] G[m][k] for m ≥ i, then the corner's
    // row i, P'[i][j] (j ≥ i), which needs U and Y of row i only: each row of U is read while
    // its values are at hand, and every result is probed as it is made.
    // The results U[i][j], j ≥ NAV, that no corner entry reads: a non-finite U[i][j] with
    // G[r][j] structurally non-zero for some r ≥ i makes Y[i][r] and so P'[i][r] non-finite
    // (a product or sum with a non-finite operand is never finite), which the corner's probe
    // sees; only the others are probed (last, before the commit that reads them).
    let uncovered: Vec<String> = (NAV..N)
        .flat_map(|j| (0..NAV).map(move |i| (i, j)))
        .filter(|&(i, j)| !g.iter().any(|x| x.col == j && x.row >= i))
        .map(|(i, j)| format!(" + {} * z", uref(j, i)))
        .collect();
    s.push_str("    let mut probe = z;\n");
    s.push_str("    // Y = U Gᵀ and the corner P'[i][j], j ≥ i, row by row of U.\n");
    for i in 0..NAV {
        for m in i..NAV {
            let terms: Vec<(String, bool)> = g_row(m)
                .map(|x| {
                    (
                        format!("{} * {}", uref(x.col, i), gname(x.row, x.col)),
                        x.negated,
                    )
                })
                .collect();
            let _ = writeln!(s, "    let y{i}_{m} = {};", sum(&terms));
        }
        for j in i..NAV {
            let mut ay = vec![(format!("y{i}_{j}"), false)];
            for &(r, m, name, neg) in &h {
                if r == j {
                    ay.push((format!("{name} * y{i}_{m}"), neg));
                }
            }
            let mut expr = format!("{} + {}", uref(j, i), paren(&ay));
            // Q_d = Q_c Δt + ½Δt (G Q_c + Q_c Gᵀ), Q_c = diag(0₃, q_a I₃, q_g I₃).
            let q_of = |k: usize| if k < 6 { "qa" } else { "qg" };
            let mut q_terms: Vec<(String, bool)> = Vec::new();
            if j >= 3 {
                if let Some(x) = g.iter().find(|x| x.row == i && x.col == j) {
                    q_terms.push((format!("{} * {}", gname(i, j), q_of(j)), x.negated));
                }
            }
            if i >= 3 {
                if let Some(x) = g.iter().find(|x| x.row == j && x.col == i) {
                    q_terms.push((format!("{} * {}", gname(j, i), q_of(i)), x.negated));
                }
            }
            if !q_terms.is_empty() {
                let _ = write!(expr, " + {}", paren(&q_terms));
            }
            if i == j && i >= 3 {
                let _ = write!(expr, " + {}2", q_of(i));
            }
            let _ = writeln!(s, "    let c{i}_{j} = {expr};\n    probe += c{i}_{j} * z;");
        }
    }
    // Every result finite (a non-finite entry times zero is NaN), else nothing is written.
    let _ = writeln!(s, "    probe = probe{};", uncovered.concat());
    s.push_str("    if probe != z {\n        return false;\n    }\n");
    for j in 0..NAV {
        for i in 0..=j {
            let _ = writeln!(s, "    p[{j}][{i}] = c{i}_{j};");
            if i != j {
                let _ = writeln!(s, "    p[{i}][{j}] = c{i}_{j};");
            }
        }
    }
    for j in NAV..N {
        for i in 0..NAV {
            let _ = writeln!(s, "    p[{j}][{i}] = {};", uref(j, i));
            let _ = writeln!(s, "    p[{i}][{j}] = {};", uref(j, i));
        }
    }
    s.push_str("    true\n}\n");
    s
}

/// The columns where the LOS rows of H can be non-zero (module doc of
/// `nav-core/src/seeker_ins/measurement.rs`): position (H1), attitude (H3) and the gimbal
/// angle error of the component (H6).
const LOS_PITCH: [usize; 7] = [0, 1, 2, 6, 7, 8, 15];
const LOS_YAW: [usize; 7] = [0, 1, 2, 6, 7, 8, 16];
/// Columns of P per block of the generated rank-two update.
const UPDATE_BLOCK: usize = 4;

/// The LOS update kernels source.
fn los_source() -> String {
    let mut s = String::from(HEADER);
    s.push_str(
        "//! The LOS update of the 17-state seeker INS written out from the sparsity of its two\n\
         //! measurement rows (non-zero only in position, attitude and the component's gimbal angle\n\
         //! error: 7 of 17 columns): `P h` and `a · h` over those columns, and the rank-two update\n\
         //! `P ← P − k₁K₁ᵀ − k₂K₂ᵀ` of the upper triangle, mirrored. Each sum runs in column\n\
         //! order, as the dense forms they replace (same bits: the skipped terms are zeros).\n\
         //! Generator: `xtask/src/gen.rs`.\n\n\
         use crate::Real;\n\n",
    );
    for (name, cols) in [("pitch", LOS_PITCH), ("yaw", LOS_YAW)] {
        let list = cols.map(|c| c.to_string()).join(", ");
        let _ = writeln!(
            s,
            "/// `P h` for a {name} row `h` (non-zero only in columns {list}), reading the upper\n\
             /// triangle of `p` (column-major, `p[col][row]`).\n\
             #[inline(always)]\n\
             pub(in crate::seeker_ins) fn p_h_{name}<T: Real>(p: &[[T; 17]; 17], h: &[T; 17]) -> [T; 17] {{"
        );
        s.push_str("    [\n");
        for i in 0..N {
            let terms: Vec<(String, bool)> = cols
                .iter()
                .map(|&j| (format!("h[{j}] * {}", p_upper(i, j)), false))
                .collect();
            let _ = writeln!(s, "        {},", sum(&terms));
        }
        s.push_str("    ]\n}\n\n");
        let _ = writeln!(
            s,
            "/// `a · h` for a {name} row `h` (columns {list}).\n\
             #[inline(always)]\n\
             pub(in crate::seeker_ins) fn dot_{name}<T: Real>(a: &[T; 17], h: &[T; 17]) -> T {{"
        );
        let terms: Vec<(String, bool)> = cols
            .iter()
            .map(|&j| (format!("a[{j}] * h[{j}]"), false))
            .collect();
        let _ = writeln!(s, "    {}\n}}\n", sum(&terms));
    }
    s.push_str(
        "/// The rank-two update `P[i,j] − k1[i] kk1[j] − k2[i] kk2[j]` (one expression for both\n\
         /// triangles).\n\
         #[inline(always)]\n\
         fn updated<T: Real>(pij: T, k1i: T, kk1j: T, k2i: T, kk2j: T) -> T {\n\
         \x20   pij - k1i * kk1j - k2i * kk2j\n\
         }\n\n\
         /// `true` when every variance of the rank-two update is finite and ≥ 0 (`p` unchanged):\n\
         /// each `≥ 0` (false for NaN), and `Σ 0 · dᵢ = 0` (NaN when one is infinite or NaN).\n\
         #[inline(always)]\n\
         pub(in crate::seeker_ins) fn rank_two_variances_ok<T: Real>(\n\
         \x20   p: &[[T; 17]; 17],\n\
         \x20   k1: &[T; 17],\n\
         \x20   kk1: &[T; 17],\n\
         \x20   k2: &[T; 17],\n\
         \x20   kk2: &[T; 17],\n\
         ) -> bool {\n\
         \x20   let z = T::zero();\n",
    );
    // Straight line: the 17 variances, one sign test each and one finiteness probe for all
    // (a classification of each variance costs about 30 instructions on the M4F).
    for i in 0..N {
        let _ = writeln!(
            s,
            "    let d{i} = updated(p[{i}][{i}], k1[{i}], kk1[{i}], k2[{i}], kk2[{i}]);"
        );
    }
    let signs: Vec<String> = (0..N).map(|i| format!("d{i} >= z")).collect();
    let probe: Vec<String> = (0..N).map(|i| format!(" + d{i} * z")).collect();
    let _ = writeln!(
        s,
        "    {} && z{} == z\n}}\n",
        signs.join(" && "),
        probe.concat()
    );
    s.push_str(
        "/// `P ← P − k₁K₁ᵀ − k₂K₂ᵀ` on the upper triangle, mirrored (exactly symmetric), and the\n\
         /// stabilising noise in the same pass: each variance `v` becomes `v + v · delta`\n\
         /// (dimensionless `delta`; 0 adds nothing).\n\
         #[allow(clippy::too_many_lines)]\n\
         #[inline(never)]\n\
         pub(in crate::seeker_ins) fn rank_two_update<T: Real>(\n\
         \x20   p: &mut [[T; 17]; 17],\n\
         \x20   k1: &[T; 17],\n\
         \x20   kk1: &[T; 17],\n\
         \x20   k2: &[T; 17],\n\
         \x20   kk2: &[T; 17],\n\
         \x20   delta: T,\n\
         ) {\n",
    );
    // Blocks of four columns, rows outermost within a block: each k1[i], k2[i] read serves
    // up to four entries while the block's kk1[j], kk2[j] stay in registers.
    for j0 in (0..N).step_by(UPDATE_BLOCK) {
        let block = j0..(j0 + UPDATE_BLOCK).min(N);
        for i in 0..block.end {
            for j in block.clone().filter(|&j| i <= j) {
                let _ = writeln!(
                    s,
                    "    let v = updated(p[{j}][{i}], k1[{i}], kk1[{j}], k2[{i}], kk2[{j}]);"
                );
                if i == j {
                    let _ = writeln!(s, "    p[{j}][{i}] = v + v * delta;");
                } else {
                    let _ = writeln!(s, "    p[{j}][{i}] = v;\n    p[{i}][{j}] = v;");
                }
            }
        }
    }
    s.push_str("}\n");
    s
}

fn generated_dir() -> PathBuf {
    root().join("nav-core/src/seeker_ins/generated")
}

/// The generated files: (file name, contents).
fn outputs() -> Vec<(&'static str, String)> {
    vec![
        ("predict17.rs", predict_source()),
        ("los17.rs", los_source()),
    ]
}

/// `text` as `rustfmt` formats it (so `cargo fmt --check` passes on the generated files).
fn rustfmt(text: &str) -> Result<String, String> {
    use std::io::Write as _;
    use std::process::{Command, Stdio};
    let mut child = Command::new("rustfmt")
        .args(["--edition", "2021", "--emit", "stdout"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("rustfmt: {e}"))?;
    child
        .stdin
        .take()
        .ok_or("rustfmt: no stdin")?
        .write_all(text.as_bytes())
        .map_err(|e| format!("rustfmt: {e}"))?;
    let out = child
        .wait_with_output()
        .map_err(|e| format!("rustfmt: {e}"))?;
    if !out.status.success() {
        return Err(format!("rustfmt: {}", String::from_utf8_lossy(&out.stderr)));
    }
    String::from_utf8(out.stdout).map_err(|e| format!("rustfmt: {e}"))
}

/// `cargo xtask gen [--check]`.
pub fn gen(check: bool) -> Result<(), String> {
    let dir = generated_dir();
    let mut stale = Vec::new();
    for (name, text) in outputs() {
        let text = rustfmt(&text)?;
        let path = dir.join(name);
        let current = std::fs::read_to_string(&path).unwrap_or_default();
        if current == text {
            continue;
        }
        if check {
            stale.push(name);
        } else {
            std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
            std::fs::write(&path, &text).map_err(|e| format!("{}: {e}", path.display()))?;
            eprintln!("xtask: gen: wrote {}", path.display());
        }
    }
    if stale.is_empty() {
        if check {
            eprintln!("xtask: gen --check: generated files are fresh");
        }
        Ok(())
    } else {
        Err(format!(
            "gen --check: {} stale (run `cargo xtask gen` and commit)",
            stale.join(", ")
        ))
    }
}
