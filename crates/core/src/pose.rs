//! Where things are in the world at one moment: the contract between kinematics (which
//! computes it from joint values) and the renderer (which draws it).
//!
//! World frame: right-handed, metres, origin at the nominal sample centre. Camera frame:
//! OpenCV convention, `x` right, `y` down, `z` forward along the optical axis.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::direction::Direction;

/// Poses of sample, camera and lamp in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScenePose {
    /// Maps sample-frame coordinates (see [`crate::direction`]) to world coordinates.
    pub sample_to_world: Isometry3<f64>,
    /// Maps camera-frame coordinates to world coordinates.
    pub camera_to_world: Isometry3<f64>,
    /// Position of the lamp (point source) in world coordinates, metres.
    pub lamp_position: Point3<f64>,
}

impl ScenePose {
    /// A pose with the sample at the world origin (sample frame = world frame), the camera
    /// at `camera_distance` along `view` looking at the origin, and the lamp at
    /// `lamp_distance` along `light`. Image `x` follows the sample's x axis projected into
    /// the image plane (or the y axis when looking along x). Used by tests and tools that
    /// need a pose without a rig's kinematics.
    pub fn looking_at(light: Direction, view: Direction, camera_distance: f64, lamp_distance: f64) -> Self {
        let v = view.to_vector();
        let z_cam = -v; // optical axis points from the camera towards the sample
        let mut reference = Vector3::x();
        if reference.cross(&z_cam).norm() < 1e-6 {
            reference = Vector3::y();
        }
        let x_cam = (reference - z_cam * reference.dot(&z_cam)).normalize();
        let y_cam = z_cam.cross(&x_cam);
        let rot = nalgebra::Rotation3::from_basis_unchecked(&[x_cam, y_cam, z_cam]);
        let camera_to_world =
            Isometry3::from_parts(Translation3::from(v * camera_distance), UnitQuaternion::from_rotation_matrix(&rot));
        ScenePose {
            sample_to_world: Isometry3::identity(),
            camera_to_world,
            lamp_position: Point3::from(light.to_vector() * lamp_distance),
        }
    }

    /// Camera centre in the sample frame.
    pub fn camera_in_sample(&self) -> Point3<f64> {
        self.sample_to_world.inverse_transform_point(&Point3::from(self.camera_to_world.translation.vector))
    }

    /// Lamp position in the sample frame.
    pub fn lamp_in_sample(&self) -> Point3<f64> {
        self.sample_to_world.inverse_transform_point(&self.lamp_position)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn looking_at_points_the_optical_axis_at_the_origin() {
        for (t, p) in [(0.0, 0.0), (30.0, 40.0), (75.0, 345.0), (60.0, 180.0)] {
            let view = Direction::from_degrees(t, p);
            let pose = ScenePose::looking_at(Direction::from_degrees(45.0, 90.0), view, 1.5, 2.0);
            let origin_in_cam = pose.camera_to_world.inverse_transform_point(&Point3::origin());
            assert!(origin_in_cam.x.abs() < 1e-12 && origin_in_cam.y.abs() < 1e-12);
            assert!((origin_in_cam.z - 1.5).abs() < 1e-12);
            let back = Direction::from_vector(&pose.camera_in_sample().coords);
            assert!(back.angle_to(view) < 1e-12);
        }
    }
}
