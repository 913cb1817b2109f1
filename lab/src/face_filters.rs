//! Filters on per-face normals for `shading-stereo`: pinning, debiasing against the mesh's own
//! normals, diffusion over face neighbours, and the error against the truth's.

use glam::Vec3;
use gtsr_data::ply::TriMesh;
use gtsr_mesh::mesh::face_centroid;
use gtsr_mesh::refine::FaceNormals;

/// Per vertex of `mesh`: 1 within `radius` (along the edges) of a face marked in `free`,
/// `pin` elsewhere.
pub(crate) fn pin_scale(mesh: &TriMesh, free: &[bool], radius: f32, pin: f32) -> Vec<f32> {
    let nv = mesh.positions.len();
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for t in &mesh.triangles {
        for k in 0..3 {
            adj[t[k] as usize].push(t[(k + 1) % 3]);
            adj[t[(k + 1) % 3] as usize].push(t[k]);
        }
    }
    // Dijkstra from the free faces' vertices, up to `radius` (non-negative distances order
    // as their bit patterns).
    let mut dist = vec![f32::INFINITY; nv];
    let mut heap = std::collections::BinaryHeap::new();
    for (f, t) in mesh.triangles.iter().enumerate() {
        if free[f] {
            for &i in t {
                if dist[i as usize] > 0.0 {
                    dist[i as usize] = 0.0;
                    heap.push((std::cmp::Reverse(0u32), i));
                }
            }
        }
    }
    while let Some((std::cmp::Reverse(dbits), i)) = heap.pop() {
        let d = f32::from_bits(dbits);
        if d > dist[i as usize] {
            continue;
        }
        for &j in &adj[i as usize] {
            let nd = d + (mesh.positions[i as usize] - mesh.positions[j as usize]).length();
            if nd < dist[j as usize] && nd <= radius {
                dist[j as usize] = nd;
                heap.push((std::cmp::Reverse(nd.to_bits()), j));
            }
        }
    }
    dist.iter()
        .map(|d| if d.is_finite() { 1.0 } else { pin })
        .collect()
}

/// Fits a scene-wide tilt of `shading` from `own` proportional to the lopsidedness of the
/// eyes that see each face: `s_t = k m_t`, with `m_t` the part of `eyes` (per face, the mean
/// unit direction to the eyes that see it) tangent to the face, by least squares over the
/// faces where the two normals agree within 10 degrees; then removes `k m_t` from every solved
/// shading normal. Returns `k`.
pub(crate) fn debias(shading: &mut FaceNormals, own: &FaceNormals, eyes: &[Vec3]) -> f32 {
    let agree = 10f32.to_radians().cos();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (f, e) in eyes.iter().enumerate() {
        let (s, n) = (shading.normal[f], own.normal[f]);
        if shading.weight[f] <= 0.0 || s.dot(n) < agree {
            continue;
        }
        let m = *e - e.dot(n) * n;
        num += f64::from(s.dot(m));
        den += f64::from(m.length_squared());
    }
    if den <= 0.0 {
        return 0.0;
    }
    let k = (num / den) as f32;
    for (f, e) in eyes.iter().enumerate() {
        if shading.weight[f] > 0.0 {
            let s = shading.normal[f];
            let m = *e - e.dot(s) * s;
            shading.normal[f] = (s - k * m).normalize_or_zero();
        }
    }
    k
}

/// Per face, the faces that share an edge with it.
pub(crate) fn face_neighbours(mesh: &TriMesh) -> Vec<Vec<u32>> {
    let mut edges: std::collections::HashMap<(u32, u32), Vec<u32>> =
        std::collections::HashMap::with_capacity(mesh.triangles.len() * 3 / 2);
    for (f, t) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(f as u32);
        }
    }
    let mut out = vec![Vec::new(); mesh.triangles.len()];
    for faces in edges.values() {
        for &f in faces {
            out[f as usize].extend(faces.iter().filter(|g| **g != f));
        }
    }
    out
}

/// The explicit diffusion steps of [`diffuse`] that average a face's value over about `sigma`
/// (scene units) around it: the mean squared distance between neighbouring centroids sets
/// the variance each step adds (step size 1/2), `2 sigma^2` over the surface's two dimensions.
pub(crate) fn diffusion_steps(mesh: &TriMesh, neighbours: &[Vec<u32>], sigma: f32) -> usize {
    let centroids: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| face_centroid(mesh, *t))
        .collect();
    let (mut d2, mut n) = (0.0f64, 0usize);
    for (f, nb) in neighbours.iter().enumerate() {
        for &g in nb {
            d2 += f64::from(centroids[f].distance_squared(centroids[g as usize]));
            n += 1;
        }
    }
    let d2 = (d2 / n.max(1) as f64).max(f64::MIN_POSITIVE);
    (2.0 * f64::from(sigma).powi(2) / (0.5 * d2)).ceil() as usize
}

/// Smooths per-face vectors over the mesh by `steps` of explicit diffusion along shared
/// edges, and renormalises.
pub(crate) fn diffuse(neighbours: &[Vec<u32>], x: &[Vec3], steps: usize) -> Vec<Vec3> {
    let mut cur = x.to_vec();
    let mut next = cur.clone();
    for _ in 0..steps {
        for (f, nb) in neighbours.iter().enumerate() {
            if nb.is_empty() {
                next[f] = cur[f];
                continue;
            }
            let mean = nb.iter().map(|g| cur[*g as usize]).sum::<Vec3>() / nb.len() as f32;
            next[f] = 0.5 * (cur[f] + mean);
        }
        std::mem::swap(&mut cur, &mut next);
    }
    cur.into_iter().map(Vec3::normalize_or_zero).collect()
}

/// Replaces the variation of `shading` over lengths above `sigma` with that of `own`: each
/// solved normal is rotated by the rotation that takes the smoothed shading normals to the
/// smoothed own normals at its face (faces without a shading normal take their own in both
/// fields).
pub(crate) fn low_pass(mesh: &TriMesh, shading: &mut FaceNormals, own: &FaceNormals, sigma: f32) {
    let neighbours = face_neighbours(mesh);
    let s: Vec<Vec3> = (0..own.normal.len())
        .map(|f| {
            if shading.weight[f] > 0.0 {
                shading.normal[f]
            } else {
                own.normal[f]
            }
        })
        .collect();
    let steps = diffusion_steps(mesh, &neighbours, sigma);
    let s_bar = diffuse(&neighbours, &s, steps);
    let o_bar = diffuse(&neighbours, &own.normal, steps);
    for f in 0..s.len() {
        if shading.weight[f] > 0.0 && s_bar[f] != Vec3::ZERO && o_bar[f] != Vec3::ZERO {
            let q = glam::Quat::from_rotation_arc(s_bar[f], o_bar[f]);
            shading.normal[f] = (q * shading.normal[f]).normalize_or_zero();
        }
    }
}

/// Removes the part of `shading`'s departure from `own` that depends on the normal's direction
/// alone: directions are binned on a latitude-longitude grid, each bin's sums of shading and
/// own normals smoothed over directions by a Gaussian kernel of `tau_deg`, and every solved
/// normal rotated by its bin's rotation from the smoothed shading mean to the smoothed own one.
pub(crate) fn orient_debias(shading: &mut FaceNormals, own: &FaceNormals, tau_deg: f32) {
    const LAT: usize = 45;
    const LON: usize = 90;
    let bin = |n: Vec3| {
        let lat = ((n.z.clamp(-1.0, 1.0).acos() / std::f32::consts::PI) * LAT as f32) as usize;
        let lon = ((n.y.atan2(n.x) / std::f32::consts::TAU + 0.5) * LON as f32) as usize;
        lat.min(LAT - 1) * LON + lon.min(LON - 1)
    };
    let centre = |b: usize| {
        let (lat, lon) = (b / LON, b % LON);
        let t = (lat as f32 + 0.5) / LAT as f32 * std::f32::consts::PI;
        let p = ((lon as f32 + 0.5) / LON as f32 - 0.5) * std::f32::consts::TAU;
        Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    };
    let mut s_sum = vec![Vec3::ZERO; LAT * LON];
    let mut o_sum = vec![Vec3::ZERO; LAT * LON];
    for f in 0..own.normal.len() {
        if shading.weight[f] > 0.0 {
            let b = bin(shading.normal[f]);
            s_sum[b] += shading.normal[f];
            o_sum[b] += own.normal[f];
        }
    }
    let centres: Vec<Vec3> = (0..LAT * LON).map(centre).collect();
    let tau = tau_deg.to_radians();
    let rot: Vec<glam::Quat> = centres
        .iter()
        .map(|c| {
            let (mut s, mut o) = (Vec3::ZERO, Vec3::ZERO);
            for (b, d) in centres.iter().enumerate() {
                let a = c.dot(*d).clamp(-1.0, 1.0).acos();
                if a < 3.0 * tau {
                    let k = (-0.5 * (a / tau).powi(2)).exp();
                    s += k * s_sum[b];
                    o += k * o_sum[b];
                }
            }
            let (s, o) = (s.normalize_or_zero(), o.normalize_or_zero());
            if s == Vec3::ZERO || o == Vec3::ZERO {
                glam::Quat::IDENTITY
            } else {
                glam::Quat::from_rotation_arc(s, o)
            }
        })
        .collect();
    for f in 0..own.normal.len() {
        if shading.weight[f] > 0.0 {
            let q = rot[bin(shading.normal[f])];
            shading.normal[f] = (q * shading.normal[f]).normalize_or_zero();
        }
    }
}

/// Per face where both have a normal, the angle between two sets of face normals (degrees,
/// median / mean; NaN where none).
pub(crate) fn face_error(x: &FaceNormals, truth: &FaceNormals) -> (f32, f64) {
    crate::concavity::median_mean(&mut crate::concavity::face_angles(x, truth))
}
