//! Voxel traversal shared by the methods that march rays through a grid of their own (Radiance Hints'
//! occupancy grid, the photon grid's V-grid): the 3D DDA of Amanatides and Woo (1987), one voxel per
//! step, in grid coordinates (a voxel is a unit cube; voxel `v` spans `v .. v + 1`).

use bevy::math::{IVec3, Vec3};

/// A ray's walk through the voxels it crosses, in grid coordinates. Starts in the voxel containing the
/// origin; [`VoxelWalk::advance`] moves to the next voxel the ray enters.
#[derive(Clone, Copy, Debug)]
pub struct VoxelWalk {
    origin: Vec3,
    direction: Vec3,
    step: IVec3,
    /// Ray parameter per voxel crossed, per axis (∞ where the ray does not move along it).
    inv: Vec3,
    /// Ray parameter of the next voxel boundary per axis.
    t_max: Vec3,
    voxel: IVec3,
    /// Ray parameter where the ray entered the current voxel.
    t: f32,
}

/// Components smaller than this are treated as zero (the ray never crosses that axis).
const STILL: f32 = 1e-8;

impl VoxelWalk {
    /// The walk of the ray `origin + t direction` (grid coordinates; `direction` need not be unit: `t`
    /// is in its lengths) from `t = 0`.
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        let moving = direction.abs().cmpge(Vec3::splat(STILL));
        let inv = Vec3::select(moving, Vec3::ONE / direction.abs().max(Vec3::splat(STILL)), Vec3::INFINITY);
        let mut walk = Self {
            origin,
            direction,
            step: Vec3::select(moving, direction.signum(), Vec3::ZERO).as_ivec3(),
            inv,
            t_max: Vec3::ZERO,
            voxel: IVec3::ZERO,
            t: 0.0,
        };
        walk.restart(0.0);
        walk
    }

    /// Restarts the walk at ray parameter `t`: in the voxel containing `origin + t direction` (a skip
    /// over space known to be empty, such as a coarse cell of a two-level traversal).
    pub fn restart(&mut self, t: f32) {
        let p = self.origin + self.direction * t;
        let cell = p.floor();
        let frac = p - cell;
        let to_boundary = Vec3::select(self.direction.cmplt(Vec3::ZERO), frac, Vec3::ONE - frac);
        // 0 × ∞ is NaN on an axis the ray does not move along: that axis never steps.
        let t_max = to_boundary * self.inv + t;
        self.t_max = Vec3::select(self.inv.is_finite_mask(), t_max, Vec3::INFINITY);
        self.voxel = cell.as_ivec3();
        self.t = t;
    }

    /// The voxel the ray is in.
    pub fn voxel(&self) -> IVec3 {
        self.voxel
    }

    /// The ray parameter where the ray entered the current voxel (the restart parameter for the first).
    pub fn t(&self) -> f32 {
        self.t
    }

    /// Moves to the next voxel along the ray; returns the ray parameter where it enters it.
    pub fn advance(&mut self) -> f32 {
        let t = &mut self.t_max;
        let axis = if t.x < t.y && t.x < t.z {
            0
        } else if t.y < t.z {
            1
        } else {
            2
        };
        self.t = t[axis];
        t[axis] += self.inv[axis];
        self.voxel[axis] += self.step[axis];
        self.t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_diagonal_walk_visits_each_crossed_voxel_once_in_order() {
        let mut walk = VoxelWalk::new(Vec3::new(0.5, 0.25, 0.5), Vec3::new(1.0, 1.0, 0.0).normalize());
        let mut seen = vec![walk.voxel()];
        let mut last_t = walk.t();
        for _ in 0..6 {
            let t = walk.advance();
            assert!(t >= last_t, "parameters grow: {t} after {last_t}");
            last_t = t;
            seen.push(walk.voxel());
        }
        // From (0.5, 0.25) at 45°: x crosses at 0.5/cos, y at 0.75/cos, so x first.
        assert_eq!(&seen[..4], &[IVec3::new(0, 0, 0), IVec3::new(1, 0, 0), IVec3::new(1, 1, 0), IVec3::new(2, 1, 0)]);
        for pair in seen.windows(2) {
            assert_eq!((pair[1] - pair[0]).abs().element_sum(), 1, "one face at a time: {pair:?}");
        }
    }

    #[test]
    fn an_axis_ray_enters_voxels_at_their_faces() {
        let mut walk = VoxelWalk::new(Vec3::new(2.25, 0.5, 0.5), Vec3::NEG_X);
        assert_eq!(walk.voxel(), IVec3::new(2, 0, 0));
        assert!((walk.advance() - 0.25).abs() < 1e-6);
        assert_eq!(walk.voxel(), IVec3::new(1, 0, 0));
        assert!((walk.advance() - 1.25).abs() < 1e-6);
        walk.restart(2.0);
        assert_eq!(walk.voxel(), IVec3::new(0, 0, 0));
        assert!((walk.advance() - 2.25).abs() < 1e-6);
        assert_eq!(walk.voxel(), IVec3::new(-1, 0, 0));
    }
}
