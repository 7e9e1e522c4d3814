"""torchakvf.threads: single_threaded blocks nest and overlap across threads."""
import torch


def test_single_threaded_restores_the_thread_count_also_when_overlapping():
    import threading

    from torchakvf.threads import single_threaded
    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        with single_threaded():
            assert torch.get_num_threads() == 1
            with single_threaded():
                assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        # Two threads whose blocks overlap (A enters, B enters, A leaves, B leaves): the process
        # ends with its thread count, not with the 1 that B would have saved.
        a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

        def first():
            with single_threaded():
                a_in.set()
                b_in.wait(5)
            a_out.set()

        def second():
            a_in.wait(5)
            with single_threaded():
                b_in.set()
                a_out.wait(5)

        ts = [threading.Thread(target=first), threading.Thread(target=second)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(10)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)
