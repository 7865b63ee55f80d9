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

/// A spinner on stderr labelled `what`, with the elapsed time and a message (drawn on a
/// terminal only; hidden when stderr is redirected).
pub fn spinner(what: &str) -> ProgressBar {
    use std::io::IsTerminal;
    let target = if std::io::stderr().is_terminal() {
        indicatif::ProgressDrawTarget::stderr()
    } else {
        indicatif::ProgressDrawTarget::hidden()
    };
    let bar = ProgressBar::with_draw_target(None, target);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!("{{spinner}} {what} {{elapsed}} {{msg}}"))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}
