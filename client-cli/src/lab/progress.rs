//! A spinner on stderr for the progress events of long work
//! ([`fissure_engine::progress`]): while a command loads a scene (the demo,
//! `bench loop`, `study`) or meshes a model (`mesh from-surface`,
//! `mesh generate`), it shows the current stage and the time spent, and
//! clears itself when the work is done. Nothing is drawn when stderr is not a
//! terminal.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::field::{Field, Visit};
use tracing_subscriber::layer::{Context, Layer};

/// The `tracing` layer that drives the spinner (filter it to
/// [`fissure_engine::progress::TARGET`], see [`ProgressLayer::filter`]).
#[derive(Clone)]
pub struct ProgressLayer {
    bar: Arc<Mutex<Option<ProgressBar>>>,
    target: fn() -> ProgressDrawTarget,
}

impl std::fmt::Debug for ProgressLayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProgressLayer").finish_non_exhaustive()
    }
}

impl ProgressLayer {
    /// A spinner on stderr.
    pub fn stderr() -> Self {
        Self::with_target(ProgressDrawTarget::stderr)
    }

    /// A spinner drawn to the targets `target` makes (hidden ones in tests).
    pub fn with_target(target: fn() -> ProgressDrawTarget) -> Self {
        Self {
            bar: Arc::new(Mutex::new(None)),
            target,
        }
    }

    /// The filter the layer is meant to run behind: progress events only.
    pub fn filter() -> tracing_subscriber::filter::Targets {
        tracing_subscriber::filter::Targets::new()
            .with_target(fissure_engine::progress::TARGET, tracing::Level::INFO)
    }

    /// The stage shown now, if the spinner is up.
    pub fn current(&self) -> Option<String> {
        self.bar
            .lock()
            .ok()?
            .as_ref()
            .map(|b| b.message().to_string())
    }
}

#[derive(Default)]
struct Fields {
    message: String,
    done: bool,
}

impl Visit for Fields {
    fn record_bool(&mut self, field: &Field, value: bool) {
        if field.name() == "done" {
            self.done = value;
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.message = format!("{value:?}");
        }
    }
}

impl<S: tracing::Subscriber> Layer<S> for ProgressLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _: Context<'_, S>) {
        if event.metadata().target() != fissure_engine::progress::TARGET {
            return;
        }
        let mut fields = Fields::default();
        event.record(&mut fields);
        let Ok(mut bar) = self.bar.lock() else {
            return;
        };
        if fields.done {
            if let Some(b) = bar.take() {
                b.finish_and_clear();
            }
            return;
        }
        let b = bar.get_or_insert_with(|| {
            let b = ProgressBar::with_draw_target(None, (self.target)());
            b.set_style(
                ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            b.enable_steady_tick(Duration::from_millis(120));
            b
        });
        b.set_message(fields.message);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    /// Stages show as the spinner's message, the last one current; other
    /// events leave it alone; the done event takes it down; a new stage puts
    /// it up again.
    #[test]
    fn stages_drive_the_spinner_until_done() {
        let layer = ProgressLayer::with_target(ProgressDrawTarget::hidden);
        let probe = layer.clone();
        let subscriber = tracing_subscriber::registry().with(layer);
        tracing::subscriber::with_default(subscriber, || {
            assert_eq!(probe.current(), None);
            fissure_engine::progress::stage("scene cube: building the model");
            assert_eq!(
                probe.current().as_deref(),
                Some("scene cube: building the model")
            );
            tracing::warn!("an unrelated warning");
            fissure_engine::progress::stage(format_args!("setting up the {} solver", "compliance"));
            assert_eq!(
                probe.current().as_deref(),
                Some("setting up the compliance solver")
            );
            fissure_engine::progress::done("scene cube loaded in 0.1 s");
            assert_eq!(probe.current(), None);
            fissure_engine::progress::stage("again");
            assert_eq!(probe.current().as_deref(), Some("again"));
        });
    }
}
