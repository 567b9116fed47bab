//! # bevy_diffuse_gi
//!
//! Dynamic diffuse global illumination for Bevy: bounced light that updates every frame, with no baking
//! and no ray-tracing hardware.
//!
//! ```no_run
//! use bevy::prelude::*;
//! use bevy_diffuse_gi::prelude::*;
//!
//! App::new()
//!     .add_plugins((DefaultPlugins, DiffuseGiPlugin::default()))
//!     .run();
//! ```
//!
//! Besides the GI methods, the crate carries what they are measured with: a CPU scene snapshot
//! ([`scene`]), a path-traced ground truth ([`reference`]), the error metrics of `shared/METRICS.md`
//! ([`metrics`]), the standard scenes ([`scenes`]) and a headless renderer ([`headless`]).

pub mod hdr_image;
pub mod headless;
pub mod light;
pub mod metrics;
#[cfg(feature = "reference")]
pub mod reference;
pub mod sampling;
pub mod scene;
pub mod scenes;
pub mod sh;

use bevy::prelude::*;

/// Everything a user needs in scope.
pub mod prelude {
    pub use crate::DiffuseGiPlugin;
    pub use crate::light::GiLight;
}

/// The plugin: adds every GI method's render passes and the scene snapshot. Anything without the crate's
/// components costs nothing.
#[derive(Default)]
pub struct DiffuseGiPlugin;

impl Plugin for DiffuseGiPlugin {
    fn build(&self, app: &mut App) {
        app.register_type::<light::GiLight>()
            .add_plugins(scene::SceneSnapshotPlugin);
    }
}
