//! What every method's settings component shares: clamping each field to its valid range, naming the
//! fields that were not in it, and warning once per entity and field.

use bevy::platform::collections::HashSet;
use bevy::prelude::*;

/// A method's user-facing settings component that validates itself.
pub trait GiSettings: Component + Clone {
    /// The component's name in warnings (`"RsmGatherSettings"`).
    const NAME: &'static str;

    /// Clamps every field to its valid range, naming in `c` each field that was not.
    fn clamp(&mut self, c: &mut Clamped);

    /// The settings with every field in its valid range, and each field that was not, with the value
    /// used instead.
    fn sanitized(&self) -> (Self, Vec<(&'static str, String)>) {
        let mut s = self.clone();
        let mut c = Clamped::default();
        s.clamp(&mut c);
        (s, c.fields)
    }
}

/// Collects the fields a sanitisation changed.
#[derive(Default, Debug)]
pub struct Clamped {
    pub fields: Vec<(&'static str, String)>,
}

impl Clamped {
    /// Clamps an integer field to `lo..=hi`.
    pub fn uint(&mut self, v: &mut u32, lo: u32, hi: u32, name: &'static str) {
        if !(lo..=hi).contains(v) {
            *v = (*v).clamp(lo, hi);
            self.fields.push((name, v.to_string()));
        }
    }

    /// Clamps a float field to `lo..=hi`; a NaN or infinite value becomes `default`.
    pub fn float(&mut self, v: &mut f32, lo: f32, hi: f32, default: f32, name: &'static str) {
        if !v.is_finite() {
            *v = default;
        } else if !(lo..=hi).contains(v) {
            *v = v.clamp(lo, hi);
        } else {
            return;
        }
        self.fields.push((name, v.to_string()));
    }
}

/// Warns once per entity and field about settings that had to be clamped (the plugin then uses the
/// clamped value, every frame, without further warnings).
pub(crate) fn validate_settings<T: GiSettings>(
    changed: Query<(Entity, &T), Changed<T>>,
    mut warned: Local<HashSet<(Entity, &'static str)>>,
    mut warnings: ResMut<crate::DiffuseGiWarnings>,
) {
    for (entity, settings) in &changed {
        for (field, value) in settings.sanitized().1 {
            if warned.insert((entity, field)) {
                crate::gi_warning(
                    &mut warnings,
                    format!("bevy_diffuse_gi: {} on {entity}: invalid `{field}`, using {value}", T::NAME),
                );
            }
        }
    }
}
