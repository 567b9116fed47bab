//! What changed between two states of the [`SceneSnapshot`](super::SceneSnapshot), for the methods that
//! keep the paths they traced and redo only those a change touches (the photon grid's photon paths and
//! probe rays, the VPLs' walks and traced shadow maps): the world boxes of the instances that moved,
//! and the segment and ray tests against them.

use bevy::math::Vec3;

/// An instance as a method's last run saw it: key, version (bumped by every change of its transform,
/// mesh or material), world bounds, and whatever else the method needs to know of it (`T`).
pub type InstanceRecord<T> = (u64, u64, (Vec3, Vec3), T);

/// The instances of `snapshot` as [`InstanceRecord`]s, in the snapshot's order (by key), with `extra(i)`.
pub fn instance_records<T>(snapshot: &super::SceneSnapshot, extra: impl Fn(&super::SnapshotInstance) -> T) -> Vec<InstanceRecord<T>> {
    snapshot.instances().iter().map(|i| (i.key, i.version, i.bounds, extra(i))).collect()
}

/// The instances that changed between two tables sorted by key (moved, changed, added or removed): the
/// old and the new bounds of each, with its record's `T`.
pub fn changed_boxes<T: Copy>(old: &[InstanceRecord<T>], new: &[InstanceRecord<T>]) -> Vec<((Vec3, Vec3), T)> {
    let mut boxes = Vec::new();
    let (mut a, mut b) = (old.iter().peekable(), new.iter().peekable());
    loop {
        let (was, is) = match (a.peek(), b.peek()) {
            (None, None) => break,
            (Some(x), Some(y)) if x.0 == y.0 => (a.next(), b.next()),
            (Some(x), Some(y)) if x.0 < y.0 => (a.next(), None),
            (Some(_), None) => (a.next(), None),
            _ => (None, b.next()),
        };
        if let (Some(x), Some(y)) = (was, is)
            && x.1 == y.1
        {
            continue;
        }
        boxes.extend(was.into_iter().chain(is).map(|&(_, _, bounds, extra)| (bounds, extra)));
    }
    boxes
}

/// Whether the segment from `a` to `b` meets the box `(lo, hi)` (slab test; a degenerate segment is
/// a point).
pub fn segment_meets_box(a: Vec3, b: Vec3, (lo, hi): (Vec3, Vec3)) -> bool {
    ray_meets_box(a, b - a, 1.0, (lo, hi))
}

/// Whether the ray `origin + t·direction`, `0 ≤ t ≤ t_max`, meets the box `(lo, hi)` (`t_max` may be
/// infinite).
pub fn ray_meets_box(origin: Vec3, direction: Vec3, t_max: f32, (lo, hi): (Vec3, Vec3)) -> bool {
    let (mut t0, mut t1) = (0.0f32, t_max);
    for k in 0..3 {
        if direction[k].abs() < 1e-12 {
            if origin[k] < lo[k] || origin[k] > hi[k] {
                return false;
            }
            continue;
        }
        let inv = 1.0 / direction[k];
        let (mut near, mut far) = ((lo[k] - origin[k]) * inv, (hi[k] - origin[k]) * inv);
        if near > far {
            std::mem::swap(&mut near, &mut far);
        }
        t0 = t0.max(near);
        t1 = t1.min(far);
        if t0 > t1 {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_and_rays_meet_boxes_they_cross_and_miss_the_others() {
        let b = (Vec3::splat(-1.0), Vec3::splat(1.0));
        assert!(segment_meets_box(Vec3::new(-5.0, 0.0, 0.0), Vec3::new(5.0, 0.0, 0.0), b));
        assert!(segment_meets_box(Vec3::ZERO, Vec3::ZERO, b), "a point inside");
        assert!(!segment_meets_box(Vec3::new(-5.0, 0.0, 0.0), Vec3::new(-2.0, 0.0, 0.0), b), "stops short");
        assert!(!segment_meets_box(Vec3::new(-5.0, 2.0, 0.0), Vec3::new(5.0, 2.0, 0.0), b), "passes beside");
        assert!(segment_meets_box(Vec3::new(0.5, 0.5, 0.5), Vec3::new(3.0, 3.0, 3.0), b), "starting inside");
        assert!(!segment_meets_box(Vec3::new(-3.0, 0.0, 0.0), Vec3::new(0.0, 3.5, 0.0), b), "cutting past its corner");
        assert!(segment_meets_box(Vec3::new(-3.0, 0.0, 0.0), Vec3::new(0.0, 1.4, 0.0), b), "cutting its corner");
        assert!(ray_meets_box(Vec3::new(-5.0, 0.0, 0.0), Vec3::X, f32::INFINITY, b));
        assert!(!ray_meets_box(Vec3::new(-5.0, 0.0, 0.0), Vec3::NEG_X, f32::INFINITY, b), "points away");
        assert!(ray_meets_box(Vec3::new(-5.0, 0.9, 0.0), Vec3::new(1.0, 0.01, 0.0), f32::INFINITY, b), "grazes a face");
    }

    #[test]
    fn only_instances_that_changed_give_their_old_and_new_boxes() {
        let at = |x: f32| (Vec3::splat(x), Vec3::splat(x + 1.0));
        let old = vec![(1, 0, at(0.0), ()), (2, 0, at(5.0), ()), (3, 0, at(9.0), ())];
        let new = vec![(1, 0, at(0.0), ()), (2, 1, at(6.0), ()), (4, 0, at(20.0), ())];
        let boxes: Vec<_> = changed_boxes(&old, &new).into_iter().map(|(b, _)| b).collect();
        assert_eq!(boxes, vec![at(5.0), at(6.0), at(9.0), at(20.0)], "moved (old, new), removed, added; the still one left out");
    }
}
