// SIGINT/SIGTERM handling without async-signal hazards: the signals are blocked
// in every thread; one watcher thread receives them.
//
// What a signal does: termination_requested() becomes true and wait_for_termination()
// returns, so that a subcommand's loop stops cleanly (run keeps its position, record
// closes its log complete, evaluate removes its unfinished estimates). A subcommand
// that does not take notice within the grace period (0.5 s) -- blocked opening a FIFO,
// inside a long computation -- is ended by the watcher: the temporary files registered
// with config::register_scratch_file are removed, a line names the signal on stderr,
// and the process exits with 128 + the signal (130 for SIGINT, 143 for SIGTERM).
// A clean stop that takes notice gets up to 10 s more; a second signal ends the
// process at once the same way. Outputs are therefore complete or absent.
#pragma once

#include <atomic>
#include <functional>

namespace ve::app {

/// Call first in main(), before any thread (Fast DDS included) starts, so that
/// every thread inherits the blocked mask.
void block_termination_signals();

/// Starts the watcher thread described above (once; after block_termination_signals).
/// Without it (unit tests), wait_for_termination() takes the signals itself.
void start_termination_watcher();

/// True once SIGINT or SIGTERM arrived. A true answer tells the watcher that the
/// caller is stopping cleanly (it then waits up to 10 s before ending the process).
bool termination_requested();

/// Set when SIGINT or SIGTERM arrived, for code that polls a cancel flag (it does
/// not count as taking notice: check termination_requested() once it returns).
const std::atomic<bool>& termination_flag();

/// While it lives, `wake` is called (from the watcher thread, once) when SIGINT or
/// SIGTERM arrives, e.g. to stop a source whose read() sleeps until a far-off sample
/// is due. The destructor waits for a call in progress. At most one at a time.
class TerminationCallback {
 public:
  explicit TerminationCallback(std::function<void()> wake);
  ~TerminationCallback();
  TerminationCallback(const TerminationCallback&) = delete;
  TerminationCallback& operator=(const TerminationCallback&) = delete;
};

/// The signal that arrived (SIGINT or SIGTERM), 0 if none.
int termination_signal();

/// Waits up to timeout_s for SIGINT or SIGTERM. True when one arrived (also when
/// it arrived before the call); counts as taking notice, like termination_requested().
bool wait_for_termination(double timeout_s);

/// Exit code of a job that a signal ended before it was done: 128 + the signal.
int interrupted_exit_code();

}  // namespace ve::app
