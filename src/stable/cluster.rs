//! Clustering resting poses modulo rotation about gravity.
//!
//! A resting pose up to yaw is fully described by the gravity direction in
//! the model frame, a unit vector. Settled drops (unsettled ones never count)
//! are clustered by angle with a deterministic leader pass in drop-index order
//! followed by one reassignment to the nearest final centre, so the result is
//! a pure function of the set of drops: merging shards or resuming a run gives
//! exactly the clusters of an uninterrupted run.
//!
//! Objects that roll (cylinders on their side, spheres) have a continuum of
//! rest poses. Their gravity directions lie on a great circle (axis = the
//! cylinder axis) or cover the sphere; such drops are reported as one
//! *family* rather than as dozens of arbitrary small clusters.

use glam::{DMat3, DVec3};

use super::drop::DropResult;

/// Clustering parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ClusterParams {
    /// Two gravity directions closer than this (degrees) are the same pose.
    pub cluster_deg: f64,
    /// A great circle holding at least this many clusters is a rolling family.
    pub family_min_clusters: usize,
}

impl Default for ClusterParams {
    fn default() -> Self {
        ClusterParams {
            cluster_deg: 5.0,
            family_min_clusters: 8,
        }
    }
}

/// What a cluster is.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClusterKind {
    /// A discrete resting pose.
    Pose,
    /// Rolling family: gravity directions along the great circle normal to `axis`.
    Circle { axis: [f64; 3] },
    /// Gravity directions scattered over the sphere (a ball-like object).
    Scattered,
}

/// One resting pose (or family) with its statistics.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cluster {
    pub kind: ClusterKind,
    pub count: u64,
    /// count / settled drops.
    pub probability: f64,
    /// Wilson 95 % score interval of the probability.
    pub ci95: [f64; 2],
    /// Mean gravity direction in the model frame (for families: of the members,
    /// which is not itself a resting pose).
    pub gravity_in_model: [f64; 3],
    /// Canonical rotation model → plane frame (row-major), yaw fixed by
    /// [`canonical_rotation`].
    #[serde(rename = "R_model_to_plane")]
    pub r_model_to_plane: [f64; 9],
    /// Mean height of the model origin above the plane (m).
    pub height: f64,
    /// Up to three drops closest to the mean direction (indices).
    pub representatives: Vec<u64>,
}

/// Wilson score interval (95 %) for `k` successes out of `n`.
pub fn wilson95(k: u64, n: u64) -> [f64; 2] {
    if n == 0 {
        return [0.0, 1.0];
    }
    let z = 1.959963984540054;
    let n = n as f64;
    let p = k as f64 / n;
    let z2 = z * z;
    let denom = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denom;
    let half = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / denom;
    [(centre - half).max(0.0), (centre + half).min(1.0)]
}

/// Rotation taking the model frame to the plane frame (z up) such that
/// gravity `g` (model frame) maps to (0, 0, -1). Yaw rule: the model's x axis
/// (its y axis when x is within 25° of vertical) projects onto the plane's
/// +x axis. Returned row-major.
pub fn canonical_rotation(g: DVec3) -> [f64; 9] {
    let z = -g.normalize_or(DVec3::NEG_Z);
    let e = if z.dot(DVec3::X).abs() < 0.9 {
        DVec3::X
    } else {
        DVec3::Y
    };
    let x = (e - z * e.dot(z)).normalize();
    let y = z.cross(x);
    // Rows of R are the plane axes expressed in the model frame.
    [x.x, x.y, x.z, y.x, y.y, y.z, z.x, z.y, z.z]
}

struct Group {
    sum: DVec3,
    members: Vec<usize>,
}

/// Clusters the settled drops. `drops` may be in any order; the result is
/// sorted by probability (ties: earliest member drop first).
pub fn cluster(drops: &[DropResult], params: ClusterParams) -> Vec<Cluster> {
    cluster_about(drops, params, DVec3::ZERO)
}

/// [`cluster`] for an object whose centre of mass is `com` (model frame):
/// a pose cluster's height is the model origin's at the cluster's own
/// rotation, its members' centre-of-mass heights averaged. A drop's origin
/// height is its centre's plus `g·com` (`g` its gravity in the model), so
/// for a mesh far from its origin (a box 10 km away) the plain mean of the
/// members' heights mixes their small tilts (0.2 mrad at rest) through a
/// 10 km lever: 2 mm off the plane at the cluster's rotation. With `com`
/// at the origin (or near it) it is the plain mean.
pub fn cluster_about(drops: &[DropResult], params: ClusterParams, com: DVec3) -> Vec<Cluster> {
    let mut settled: Vec<&DropResult> = drops
        .iter()
        .filter(|d| d.settled && d.gravity_in_model.is_finite())
        .collect();
    settled.sort_by_key(|d| d.index);
    let n = settled.len() as u64;
    if n == 0 {
        return Vec::new();
    }
    let dirs: Vec<DVec3> = settled
        .iter()
        .map(|d| d.gravity_in_model.normalize())
        .collect();
    let cos_t = params.cluster_deg.to_radians().cos();

    let groups = leader_groups(&dirs, cos_t);
    let mut out = Vec::new();
    let groups = take_rolling_families(groups, &dirs, &settled, n, params, &mut out);
    let groups = take_scattered(groups, &dirs, &settled, n, &mut out);
    for g in &groups {
        let mut c = make_cluster(ClusterKind::Pose, &g.members, &dirs, &settled, n);
        if com != DVec3::ZERO {
            let of_com = g.members.iter().map(|&m| settled[m].height - dirs[m].dot(com)).sum::<f64>()
                / g.members.len().max(1) as f64;
            // Gravity at the cluster's rotation: minus the third row of R.
            let r = &c.r_model_to_plane;
            c.height = of_com - DVec3::new(r[6], r[7], r[8]).dot(com);
        }
        out.push(c);
    }
    out.sort_by(|a, b| {
        b.count
            .cmp(&a.count)
            .then(a.representatives.first().cmp(&b.representatives.first()))
    });
    out
}

/// Leader clustering of the gravity directions in index order, then one
/// reassignment of every direction to the nearest final centre.
fn leader_groups(dirs: &[DVec3], cos_t: f64) -> Vec<Group> {
    // Leader pass in index order.
    let mut groups: Vec<Group> = Vec::new();
    for (i, d) in dirs.iter().enumerate() {
        let best = nearest(&groups, *d, cos_t);
        match best {
            Some(g) => {
                groups[g].sum += *d;
                groups[g].members.push(i);
            }
            None => groups.push(Group {
                sum: *d,
                members: vec![i],
            }),
        }
    }
    // One reassignment to the nearest final centre.
    let centres: Vec<DVec3> = groups.iter().map(|g| g.sum.normalize_or_zero()).collect();
    let mut assigned: Vec<Group> = centres
        .iter()
        .map(|_| Group {
            sum: DVec3::ZERO,
            members: Vec::new(),
        })
        .collect();
    for (i, d) in dirs.iter().enumerate() {
        let mut best = (0usize, f64::NEG_INFINITY);
        for (c, centre) in centres.iter().enumerate() {
            let dot = centre.dot(*d);
            if dot > best.1 {
                best = (c, dot);
            }
        }
        assigned[best.0].sum += *d;
        assigned[best.0].members.push(i);
    }
    assigned.into_iter().filter(|g| !g.members.is_empty()).collect()

}

/// Moves the groups that lie on great circles (rolling families) into
/// `out` as circle clusters; returns the rest.
fn take_rolling_families(
    mut groups: Vec<Group>,
    dirs: &[DVec3],
    settled: &[&DropResult],
    n: u64,
    params: ClusterParams,
    out: &mut Vec<Cluster>,
) -> Vec<Group> {
    // Rolling families on great circles.
    while let Some((axis, member_groups)) = find_circle(&groups, dirs, params) {
        let mut members: Vec<usize> = member_groups
            .iter()
            .flat_map(|&g| groups[g].members.iter().copied())
            .collect();
        members.sort_unstable();
        out.push(make_cluster(
            ClusterKind::Circle {
                axis: canonical_sign(axis).to_array(),
            },
            &members,
            dirs,
            settled,
            n,
        ));
        let mut keep = Vec::new();
        for (g, grp) in groups.into_iter().enumerate() {
            if !member_groups.contains(&g) {
                keep.push(grp);
            }
        }
        groups = keep;
    }
    groups
}

/// Ball-like objects: most settled drops in many small clusters (each
/// under 5 % of the drops, at least 20 of them) become one scattered
/// cluster in `out`; returns the rest.
fn take_scattered(mut groups: Vec<Group>, dirs: &[DVec3], settled: &[&DropResult], n: u64, out: &mut Vec<Cluster>) -> Vec<Group> {
    let small = |g: &Group| (g.members.len() as f64) < (0.05 * n as f64).max(2.0);
    let small_groups: Vec<usize> = (0..groups.len()).filter(|&g| small(&groups[g])).collect();
    let small_drops: usize = small_groups.iter().map(|&g| groups[g].members.len()).sum();
    if small_groups.len() >= 20 && small_drops as f64 >= 0.5 * n as f64 {
        let mut members: Vec<usize> = small_groups
            .iter()
            .flat_map(|&g| groups[g].members.iter().copied())
            .collect();
        members.sort_unstable();
        out.push(make_cluster(
            ClusterKind::Scattered,
            &members,
            dirs,
            settled,
            n,
        ));
        groups = groups
            .into_iter()
            .enumerate()
            .filter(|(g, _)| !small_groups.contains(g))
            .map(|(_, g)| g)
            .collect();
    }
    groups
}

fn nearest(groups: &[Group], d: DVec3, cos_t: f64) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (g, grp) in groups.iter().enumerate() {
        let dot = grp.sum.normalize_or_zero().dot(d);
        if dot >= cos_t && best.is_none_or(|(_, b)| dot > b) {
            best = Some((g, dot));
        }
    }
    best.map(|b| b.0)
}

fn canonical_sign(a: DVec3) -> DVec3 {
    let arr = a.to_array();
    let mut k = 0;
    for i in 1..3 {
        if arr[i].abs() > arr[k].abs() + 1e-9 {
            k = i;
        }
    }
    if arr[k] < 0.0 {
        -a
    } else {
        a
    }
}

/// Finds the great circle holding the most clusters. Accepted as a family
/// when it holds at least `family_min_clusters` clusters and the drops near
/// it are concentrated on it (at least 80 % of the drops within 3θ of the
/// circle lie within θ), which separates a rolling cylinder from a ball.
fn find_circle(
    groups: &[Group],
    dirs: &[DVec3],
    params: ClusterParams,
) -> Option<(DVec3, Vec<usize>)> {
    if groups.len() < params.family_min_clusters {
        return None;
    }
    let sin_t = params.cluster_deg.to_radians().sin();
    let sin_3t = (3.0 * params.cluster_deg)
        .to_radians()
        .min(std::f64::consts::FRAC_PI_2)
        .sin();
    let centres: Vec<DVec3> = groups.iter().map(|g| g.sum.normalize_or_zero()).collect();
    // Candidate axes from pairs of the largest clusters.
    let mut by_size: Vec<usize> = (0..groups.len()).collect();
    by_size.sort_by(|&a, &b| {
        groups[b]
            .members
            .len()
            .cmp(&groups[a].members.len())
            .then(a.cmp(&b))
    });
    by_size.truncate(48);
    let mut best: Option<(usize, usize, DVec3)> = None; // (clusters, drops, axis)
    for (ii, &i) in by_size.iter().enumerate() {
        for &j in &by_size[ii + 1..] {
            let c = centres[i].cross(centres[j]);
            if c.length() < 0.34 {
                continue; // closer than ~20° (or opposite): a poor axis
            }
            let axis = c.normalize();
            let on: Vec<usize> = (0..groups.len())
                .filter(|&g| centres[g].dot(axis).abs() < sin_t)
                .collect();
            let drops: usize = on.iter().map(|&g| groups[g].members.len()).sum();
            if best.is_none_or(|(bc, bd, _)| (on.len(), drops) > (bc, bd)) {
                best = Some((on.len(), drops, axis));
            }
        }
    }
    let (count, _, axis) = best?;
    if count < params.family_min_clusters {
        return None;
    }
    // Refine the axis: the direction least represented among member drops.
    let members: Vec<usize> = (0..groups.len())
        .filter(|&g| centres[g].dot(axis).abs() < sin_t)
        .collect();
    let mut scatter = DMat3::ZERO;
    for &g in &members {
        for &m in &groups[g].members {
            let d = dirs[m];
            scatter += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        }
    }
    let axis = smallest_eigenvector(scatter).unwrap_or(axis);
    let near = dirs.iter().filter(|d| d.dot(axis).abs() < sin_t).count();
    let wide = dirs.iter().filter(|d| d.dot(axis).abs() < sin_3t).count();
    if (near as f64) < 0.8 * wide as f64 {
        return None;
    }
    let members: Vec<usize> = (0..groups.len())
        .filter(|&g| centres[g].dot(axis).abs() < sin_t)
        .collect();
    if members.len() < params.family_min_clusters {
        return None;
    }
    Some((axis, members))
}

/// Eigenvector of the smallest eigenvalue of a symmetric 3×3 matrix, by
/// inverse-free power iteration on (tr·1 − M).
fn smallest_eigenvector(m: DMat3) -> Option<DVec3> {
    let tr = m.x_axis.x + m.y_axis.y + m.z_axis.z;
    let shifted = DMat3::from_diagonal(DVec3::splat(tr)) - m;
    let mut v = DVec3::new(0.577, 0.5774, 0.5773);
    for _ in 0..200 {
        let w = shifted * v;
        let l = w.length();
        if !l.is_finite() || l <= 0.0 {
            return None;
        }
        v = w / l;
    }
    Some(v)
}

fn make_cluster(
    kind: ClusterKind,
    members: &[usize],
    dirs: &[DVec3],
    drops: &[&DropResult],
    n: u64,
) -> Cluster {
    let sum: DVec3 = members.iter().map(|&m| dirs[m]).sum();
    let mean = sum.normalize_or_zero();
    let height =
        members.iter().map(|&m| drops[m].height).sum::<f64>() / members.len().max(1) as f64;
    let mut reps: Vec<(f64, u64)> = members
        .iter()
        .map(|&m| (-dirs[m].dot(mean), drops[m].index))
        .collect();
    reps.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let count = members.len() as u64;
    let rot_dir = if mean == DVec3::ZERO {
        dirs[members[0]]
    } else {
        mean
    };
    let mut representatives: Vec<u64> = reps.iter().take(3).map(|r| r.1).collect();
    if !matches!(kind, ClusterKind::Pose) {
        // Families: representatives are simply the earliest member drops.
        representatives = members.iter().take(3).map(|&m| drops[m].index).collect();
    }
    Cluster {
        kind,
        count,
        probability: count as f64 / n as f64,
        ci95: wilson95(count, n),
        gravity_in_model: mean.to_array(),
        r_model_to_plane: canonical_rotation(rot_dir),
        height,
        representatives,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    fn drop_with(index: u64, g: DVec3) -> DropResult {
        DropResult {
            index,
            settled: true,
            steps: 1,
            rotation: DQuat::IDENTITY,
            height: 0.1,
            gravity_in_model: g.normalize(),
        }
    }

    #[test]
    fn wilson_matches_reference_values() {
        let [lo, hi] = wilson95(50, 100);
        assert!(
            (lo - 0.4038).abs() < 1e-4 && (hi - 0.5962).abs() < 1e-4,
            "{lo} {hi}"
        );
        assert_eq!(wilson95(0, 0), [0.0, 1.0]);
    }

    #[test]
    fn canonical_rotation_maps_gravity_down_and_is_proper() {
        for g in [
            DVec3::X,
            DVec3::new(0.3, -0.2, 0.9),
            DVec3::NEG_Z,
            DVec3::new(-1.0, 0.01, 0.0),
        ] {
            let r = canonical_rotation(g);
            let m = DMat3::from_cols_array(&r).transpose();
            let down = m * g.normalize();
            assert!((down - DVec3::NEG_Z).length() < 1e-12, "{down}");
            assert!((m.determinant() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn clusters_are_order_independent_and_ignore_unsettled() {
        let mut drops = Vec::new();
        let axes = [DVec3::X, DVec3::NEG_X, DVec3::Z];
        for i in 0..90u64 {
            let jitter = DVec3::new(
                0.0,
                ((i * 7) % 5) as f64 * 0.01,
                ((i * 3) % 4) as f64 * 0.01,
            );
            drops.push(drop_with(i, axes[(i % 3) as usize] + jitter));
        }
        drops.push(DropResult {
            settled: false,
            ..drop_with(90, DVec3::Y)
        });
        let a = cluster(&drops, ClusterParams::default());
        drops.reverse();
        let b = cluster(&drops, ClusterParams::default());
        assert_eq!(a, b);
        assert_eq!(a.len(), 3);
        assert!(a
            .iter()
            .all(|c| c.count == 30 && c.kind == ClusterKind::Pose));
    }

    #[test]
    fn directions_all_over_the_sphere_become_one_scattered_family() {
        // Fibonacci sphere: 400 well-spread directions.
        let n = 400;
        let drops: Vec<DropResult> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let phi = i as f64 * 2.399963229728653;
                let r = (1.0 - z * z).sqrt();
                drop_with(i, DVec3::new(r * phi.cos(), r * phi.sin(), z))
            })
            .collect();
        let c = cluster(&drops, ClusterParams::default());
        assert_eq!(c[0].kind, ClusterKind::Scattered, "{:?}", c[0]);
        assert!(c[0].count as f64 >= 0.9 * n as f64, "{}", c[0].count);
    }

    #[test]
    fn great_circle_becomes_a_family() {
        let mut drops = Vec::new();
        for i in 0..200u64 {
            let a = i as f64 * 0.1;
            drops.push(drop_with(i, DVec3::new(a.cos(), a.sin(), 0.0)));
        }
        for i in 200..260u64 {
            drops.push(drop_with(
                i,
                if i % 2 == 0 { DVec3::Z } else { DVec3::NEG_Z },
            ));
        }
        let c = cluster(&drops, ClusterParams::default());
        assert_eq!(c.len(), 3);
        match &c[0].kind {
            ClusterKind::Circle { axis } => {
                assert!((DVec3::from_array(*axis) - DVec3::Z).length() < 1e-6)
            }
            k => panic!("{k:?}"),
        }
        assert_eq!(c[0].count, 200);
    }
}
