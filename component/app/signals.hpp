// SIGINT/SIGTERM handling without async-signal hazards: the signals are blocked
// in every thread and the main thread waits for them with a timeout.
#pragma once

namespace ve::app {

/// Call first in main(), before any thread (Fast DDS included) starts, so that
/// every thread inherits the blocked mask.
void block_termination_signals();

/// Waits up to timeout_s for SIGINT or SIGTERM. True when one arrived.
bool wait_for_termination(double timeout_s);

}  // namespace ve::app
