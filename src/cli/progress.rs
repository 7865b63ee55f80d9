//! The CLI's progress bars as the pipelines' [`Progress`](crate::pipeline::Progress).

use indicatif::ProgressBar;

/// An indicatif bar (drawn on a terminal only, as each command sets it up) fed by a pipeline.
pub struct Bar(pub ProgressBar);

impl crate::pipeline::Progress for Bar {
    fn message(&self, msg: &str) {
        self.0.set_message(msg.to_string());
    }
    fn inc(&self) {
        self.0.inc(1);
    }
}
