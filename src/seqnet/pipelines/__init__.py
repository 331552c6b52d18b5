"""seqnet.pipelines."""
