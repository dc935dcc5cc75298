//! The viewer's layout for each kind of view (a Rerun blueprint), sent with the data so that a
//! viewer, live or opening a recording, shows each picture in its own panel instead of guessing:
//! left to itself the viewer puts the pressure image into the 3D view's space, where it cannot
//! be drawn.

use rerun::blueprint::{Blueprint, ContainerLike, Horizontal, Spatial2DView, Spatial3DView, TimeSeriesView, Vertical};

use crate::entity;

/// The panels of a view: its class (Rerun's: `2D`, `3D`, `TimeSeries`), its name and the entity
/// path it shows (with what lies below it).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Panel {
    pub class: &'static str,
    pub name: String,
    pub origin: String,
}

impl Panel {
    fn new(class: &'static str, name: &str, origin: &str) -> Self {
        Panel { class, name: name.into(), origin: format!("/{}", origin.trim_start_matches('/')) }
    }

    fn container(&self) -> ContainerLike {
        match self.class {
            "2D" => Spatial2DView::new(&self.name).with_origin(self.origin.as_str()).into(),
            "3D" => Spatial3DView::new(&self.name).with_origin(self.origin.as_str()).into(),
            _ => TimeSeriesView::new(&self.name).with_origin(self.origin.as_str()).into(),
        }
    }
}

/// The first path segment of an entity path (`rates/fps` -> `rates`): the panel showing it.
fn root(path: &str) -> &str {
    path.split('/').next().unwrap_or(path)
}

/// A stream's panels in columns: the camera (the frame with the contact mask over it) above the
/// depth; the contact patch's points and force arrow in 3D, above the pressure where the bundle
/// has a force output; the time series (rates, the contact's size and depth, each on its own
/// axis, and the force and torque).
pub fn stream_columns(has_force: bool) -> Vec<Vec<Panel>> {
    let camera = root(entity::FRAME);
    let mut columns = vec![
        vec![Panel::new("2D", "camera", camera), Panel::new("2D", "depth (mm)", entity::DEPTH)],
        vec![Panel::new("3D", "contact points (mm)", root(entity::CLOUD))],
        vec![
            Panel::new("TimeSeries", "rates", root(entity::FPS)),
            Panel::new("TimeSeries", "contact pixels", entity::CONTACT_PIXELS),
            Panel::new("TimeSeries", "deepest point (mm)", entity::MAX_DEPTH_MM),
        ],
    ];
    if has_force {
        columns[1].push(Panel::new("2D", "pressure (kPa)", entity::PRESSURE));
        columns[2].push(Panel::new("TimeSeries", "force (N)", root(entity::FORCE_N[0])));
        columns[2].push(Panel::new("TimeSeries", "torque (N mm)", root(entity::TORQUE_NMM[0])));
    }
    columns
}

/// A training run's panels: the losses and the validation figures as time series, then a
/// column each for the held-out samples' inputs, truths, predictions and errors (a row per
/// sample).
pub fn training_columns(held_out: usize) -> Vec<Vec<Panel>> {
    let series = vec![
        Panel::new("TimeSeries", "training", root(entity::TRAIN_LOSS)),
        Panel::new("TimeSeries", "validation", root(entity::VAL_L1_MM)),
    ];
    let mut columns = vec![series];
    if held_out > 0 {
        columns.extend(["input", "truth", "prediction", "error"].map(|what| {
            (0..held_out)
                .map(|k| Panel::new("2D", &format!("held-out {k}: {what}"), &entity::held_out(k, what)))
                .collect()
        }));
    }
    columns
}

/// The panels of `columns` by name: a layout as [`crate::Recording::panels`] reads one back.
pub fn panels_by_name(columns: &[Vec<Panel>]) -> Vec<Panel> {
    let mut panels: Vec<Panel> = columns.iter().flatten().cloned().collect();
    panels.sort_by(|a, b| a.name.cmp(&b.name));
    panels
}

/// The blueprint of `columns`: a row of columns, each a stack of panels; the viewer adds no
/// panels of its own.
pub(crate) fn blueprint(columns: &[Vec<Panel>]) -> Blueprint {
    let column = |panels: &Vec<Panel>| -> ContainerLike { Vertical::new(panels.iter().map(Panel::container)).into() };
    Blueprint::new(Horizontal::new(columns.iter().map(column))).with_auto_views(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether some panel shows `path` (its origin is the path or lies above it).
    fn shown(columns: &[Vec<Panel>], path: &str) -> bool {
        let path = format!("/{path}");
        columns.iter().flatten().any(|p| path == p.origin || path.starts_with(&format!("{}/", p.origin)))
    }

    #[test]
    fn every_entity_a_stream_logs_has_a_panel_and_pressure_only_with_force() {
        let always = [entity::FRAME, entity::CONTACT, entity::DEPTH, entity::CLOUD, entity::FPS, entity::LATENCY_MS]
            .into_iter()
            .chain([entity::NETWORK_RAN, entity::MAX_DEPTH_MM, entity::CONTACT_PIXELS]);
        let force =
            [entity::PRESSURE, entity::FORCE_ARROW].into_iter().chain(entity::FORCE_N).chain(entity::TORQUE_NMM);
        for has_force in [false, true] {
            let columns = stream_columns(has_force);
            for path in always.clone() {
                assert!(shown(&columns, path), "{path} has no panel (force: {has_force})");
            }
            if has_force {
                for path in force.clone() {
                    assert!(shown(&columns, path), "{path} has no panel");
                }
            }
            let pressure = columns.iter().flatten().any(|p| p.origin == format!("/{}", entity::PRESSURE));
            assert_eq!(pressure, has_force);
        }
        // The frame and its mask share one panel, drawn over each other.
        let columns = stream_columns(false);
        let camera: Vec<&Panel> =
            columns.iter().flatten().filter(|p| shown(&[vec![(*p).clone()]], entity::FRAME)).collect();
        assert_eq!(camera.len(), 1);
        assert!(shown(&[vec![camera[0].clone()]], entity::CONTACT));
    }

    #[test]
    fn every_entity_a_training_run_logs_has_a_panel() {
        for held_out in [0, 1, 3] {
            let columns = training_columns(held_out);
            let series = [entity::TRAIN_LOSS, entity::LEARNING_RATE, entity::EPOCH_LOSS, entity::VAL_L1_MM];
            for path in series.into_iter().chain([entity::VAL_LOSS, entity::VAL_PRESSURE_L1_KPA]) {
                assert!(shown(&columns, path), "{path}");
            }
            for k in 0..held_out {
                for what in ["input", "truth", "prediction", "error"] {
                    assert!(shown(&columns, &entity::held_out(k, what)), "{k} {what}");
                }
            }
            let images = columns.iter().flatten().filter(|p| p.class == "2D").count();
            assert_eq!(images, 4 * held_out);
        }
    }
}
