//! SIGINT and SIGTERM for the commands that run until stopped (`watch`, `live`).

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// A flag set by the first SIGINT or SIGTERM; a second one exits at once (status 130).
pub fn stop_on_signals() -> anyhow::Result<Arc<AtomicBool>> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        let install = || -> std::io::Result<()> {
            // Registered first, so it sees the flag as the previous signal left it.
            signal_hook::flag::register_conditional_shutdown(signal, 130, Arc::clone(&stop))?;
            signal_hook::flag::register(signal, Arc::clone(&stop))?;
            Ok(())
        };
        install().map_err(|e| anyhow::anyhow!("cannot install the SIGINT/SIGTERM handler: {e}"))?;
    }
    Ok(stop)
}
